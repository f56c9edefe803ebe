#!/bin/bash
# usage: summ.sh FILE -> "full N/M, cycles C, falls F, stalls S, holds H"
f=$1
n=$(grep -c "walk," $f); full=$(grep -c "10 of 10 gait" $f)
cyc=$(grep -o "[0-9]* of 10 gait" $f | awk '{s+=$1} END {print s}')
falls=$(grep -c "fell:" $f); stalls=$(grep -c "stalled" $f); holds=$(grep -c "HOLD\|FAULT" $f)
fs=$(grep -o "mean stick force [0-9.]*" $f | awk '{s+=$4} END {printf "%.1f", s/NR}')
echo "full $full/$n, cycles $cyc, falls $falls, stalls $stalls, holds $holds, per stick $fs N"

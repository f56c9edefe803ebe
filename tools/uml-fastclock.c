/*
 * uml-fastclock: the time without a system call, preloaded into the vcan-run guest.
 *
 * User-mode Linux has no vDSO: every time call of a guest process is a system call, which UML
 * turns into a ptrace round trip through the host (about 0.1 ms on our development VM).
 * - PyBullet reads gettimeofday(2) several times per API call and per physics step for its
 *   profiling timers, so inside the guest the simulation ran 6-10 times slower than on the host,
 *   slower than real time (measured with strace -c: 85 gettimeofday calls per 20 ms tick, and
 *   `aider-exo bench nodes` in the guest: 15-20 ms of simulation per tick without this library,
 *   2.4-2.9 ms with it).
 * - Python reads clock_gettime(2) for time.monotonic() and time.time(), and python-can's recv()
 *   with a timeout reads it twice; the controller and the nodes read the clock a few dozen times
 *   a tick (about 89 us each in the guest: 2-4 ms of a 20 ms tick in each process), so where
 *   both shared the guest's one CPU with candump the nodes' answers to a SYNC came too late for
 *   the controller's read window, three ticks in a row a lost node.
 *
 * This library answers gettimeofday and clock_gettime for CLOCK_REALTIME and CLOCK_MONOTONIC
 * from the CPU's time-stamp counter, anchored on the kernel's clock of the same id: the first
 * call anchors, a call at least 10 ms later measures the slope and anchors again. A slope
 * measured over a span is trusted for at most 4 such spans (and at most a second) before the
 * next call asks the kernel and re-measures it over the longer span, so the error stays within a
 * few times the jitter of one kernel call (0.1 ms in the guest) at the start and near it later,
 * and the span grows 10, 40, 160, 640 ms, then a second. Anchors are per thread (threads never
 * race); CLOCK_MONOTONIC never goes back, across the threads of a process either (a re-anchor
 * that would step back holds the time at the highest value returned). A step of the kernel's wall
 * clock (1 ms seen in the guest, while CLOCK_MONOTONIC stayed within 2 us) shows in
 * CLOCK_REALTIME and gettimeofday at the next anchor, within a second. Every other clock, a call
 * that asks for the time zone, and any call whose counter went backwards go to the kernel. Sleeps
 * and timers stay the kernel's: a loop that sleeps to an absolute deadline read from this clock
 * wakes within this clock's error of it.
 *
 * vcan-run builds it only on x86-64 with an invariant TSC (constant_tsc and nonstop_tsc).
 */
#define _GNU_SOURCE
#include <stdint.h>
#include <sys/syscall.h>
#include <sys/time.h>
#include <time.h>
#include <unistd.h>
#include <x86intrin.h>

#define CALIBRATE_NS 10000000LL /* the first slope after 10 ms */
#define TRUST_SPANS 4            /* a slope is used for at most 4 times the span it was measured on */
#define HORIZON_MAX_NS 1000000000LL

enum { REALTIME, MONOTONIC, CLOCKS };
static const clockid_t CLOCK_IDS[CLOCKS] = {CLOCK_REALTIME, CLOCK_MONOTONIC};

struct anchor {
    uint64_t tsc;      /* 0: no anchor yet */
    int64_t ns;
    double ns_per_tsc; /* 0: no slope yet */
    int64_t horizon_ns; /* how long after the anchor the slope is used */
};

static __thread struct anchor anchors[CLOCKS];
static int64_t monotonic_high; /* the highest CLOCK_MONOTONIC returned in this process */

/* The kernel's time and the counter at that moment: of KERNEL_TRIES calls, the quickest, with the
 * counter's midpoint (a call the host or the guest delayed, by a trap or a preemption, would
 * otherwise anchor the counter as far off as the delay, measured here up to 0.75 ms). */
#define KERNEL_TRIES 3
static int64_t kernel_ns(int clock, uint64_t *tsc)
{
    struct timespec ts;
    int64_t best = 0;
    uint64_t quickest = UINT64_MAX;
    for (int i = 0; i < KERNEL_TRIES; i++) {
        uint64_t t0 = __rdtsc();
        syscall(SYS_clock_gettime, CLOCK_IDS[clock], &ts);
        uint64_t t1 = __rdtsc();
        if (t1 >= t0 && t1 - t0 < quickest) {
            quickest = t1 - t0;
            best = (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
            *tsc = t0 + (t1 - t0) / 2;
        }
    }
    if (quickest == UINT64_MAX) { /* the counter went backwards every time: no anchor from it */
        *tsc = 0;
        best = (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
    }
    return best;
}

static int64_t now_ns(int clock)
{
    struct anchor *a = &anchors[clock];
    uint64_t tsc = __rdtsc();
    if (a->ns_per_tsc > 0.0 && tsc >= a->tsc) {
        int64_t since = (int64_t)((double)(tsc - a->tsc) * a->ns_per_tsc);
        if (since < a->horizon_ns)
            return a->ns + since;
    }
    int64_t ns = kernel_ns(clock, &tsc);
    int64_t span = ns - a->ns;
    if (tsc == 0) { /* no counter to anchor on: the kernel's time, and a new slope later */
        a->tsc = 0;
        a->ns_per_tsc = 0.0;
        return ns;
    }
    if (a->tsc != 0 && span >= CALIBRATE_NS) {
        if (tsc > a->tsc) {
            a->ns_per_tsc = (double)span / (double)(tsc - a->tsc);
            a->horizon_ns = span < HORIZON_MAX_NS / TRUST_SPANS ? TRUST_SPANS * span : HORIZON_MAX_NS;
        } else {
            a->ns_per_tsc = 0.0; /* the counter went backwards: measure the slope again */
        }
    }
    if (a->tsc == 0 || span >= CALIBRATE_NS) {
        a->tsc = tsc;
        a->ns = ns;
    }
    return ns;
}

static int64_t monotonic_ns(void)
{
    int64_t ns = now_ns(MONOTONIC);
    int64_t high = __atomic_load_n(&monotonic_high, __ATOMIC_RELAXED);
    while (ns > high) {
        if (__atomic_compare_exchange_n(&monotonic_high, &high, ns, 1, __ATOMIC_RELAXED, __ATOMIC_RELAXED))
            return ns;
    }
    return high; /* another thread, or the last anchor, already returned a later time */
}

#pragma GCC diagnostic ignored "-Wnonnull-compare"
int gettimeofday(struct timeval *restrict tv, void *restrict tz)
{
    if (tz != NULL)
        return (int)syscall(SYS_gettimeofday, tv, tz);
    if (tv != NULL) { /* glibc declares it nonnull, yet the kernel accepts NULL */
        int64_t ns = now_ns(REALTIME);
        tv->tv_sec = (time_t)(ns / 1000000000LL);
        tv->tv_usec = (suseconds_t)((ns % 1000000000LL) / 1000);
    }
    return 0;
}

int clock_gettime(clockid_t id, struct timespec *ts)
{
    if ((id != CLOCK_REALTIME && id != CLOCK_MONOTONIC) || ts == NULL)
        return (int)syscall(SYS_clock_gettime, id, ts);
    int64_t ns = id == CLOCK_MONOTONIC ? monotonic_ns() : now_ns(REALTIME);
    ts->tv_sec = (time_t)(ns / 1000000000LL);
    ts->tv_nsec = (long)(ns % 1000000000LL);
    return 0;
}

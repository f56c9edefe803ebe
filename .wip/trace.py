"""Trace one walk: every N ticks, the phase, CoM, supports and forces."""
import sys, json, math, importlib, argparse
sys.path.insert(0, "/work/main"); sys.path.insert(0, "/tmp/probe")
import numpy as np
from config.loader import load_config, default_config_path, with_overrides
import config.sim_schema as _ss; _ss.ModelConfig.validate = lambda self: None
from sim.world import World
from sim.sensors import rpy_from_matrix

ap = argparse.ArgumentParser()
ap.add_argument("--mod", default="w2")
ap.add_argument("--set", action="append", default=[])
ap.add_argument("--length", type=float, default=0.10)
ap.add_argument("--seed", type=int, default=0)
ap.add_argument("--steps", type=int, default=20)
ap.add_argument("--every", type=int, default=5)
ap.add_argument("--t0", type=float, default=0)
ap.add_argument("--t1", type=float, default=1e9)
a = ap.parse_args()
ov = {"sim.mode": "full3d", "sim.patient.intention.regime": "steady"}
for s in a.set:
    k, v = s.split("=", 1)
    try: ov[k] = json.loads(v)
    except ValueError: ov[k] = v
mod = importlib.import_module(a.mod)
cfg = with_overrides(load_config(default_config_path()), ov).sim
settings = mod.gait_settings(cfg, step_length_m=a.length)
rng = np.random.default_rng(a.seed)
with World(cfg) as world:
    world.place(mod.initial_pose(cfg))
    wk = mod.Walker(world, cfg, settings, rng)
    n = [0]
    def on_tick(w, t):
        n[0] += 1
        if n[0] % a.every or not (a.t0 <= t <= a.t1):
            return
        k = wk.kin
        kin = k
        com = k.com
        an = {s: wk.ankle_xy(s) for s in "lr"}
        tips = {s: wk.tip_point(s)[:2] for s in "lr"}
        o, R = w.link_frame("trunk")
        r, p, y = rpy_from_matrix(R)
        f = lambda l: w.contact_normal_force(l)
        arms = np.round(w.arms.applied, 0)
        print(f"{t:6.2f} {wk.phase.value:6s} sw={wk.swing_leg or '-'} com=({com[0]:.3f},{com[1]:+.3f}) tgt=({wk.com_target[0]:.3f},{wk.com_target[1]:+.3f}) "
              f"ank l={an['l'][0]:.3f} r={an['r'][0]:.3f} tips l=({tips['l'][0]:.3f},{tips['l'][1]:+.2f}) r=({tips['r'][0]:.3f},{tips['r'][1]:+.2f}) "
              f"feet {f('foot_l'):4.0f} {f('foot_r'):4.0f} sticks {f('forearm_l'):4.0f} {f('forearm_r'):4.0f} m={wk.margin:+.3f} res={wk.residual:5.0f} "
              f"dbg={getattr(wk,'dbg',None)} pg={wk.pitch_goal:.3f} ankz={kin.joint_origin[w.joint_index['ankle_l']][2]:.3f},{kin.joint_origin[w.joint_index['ankle_r']][2]:.3f} exo={np.round(w.exo.applied,0).tolist()} ff={np.round(w.exo.torque_ff,0).tolist()} tgt={np.round(w.exo.target-np.array([w.q[w.joint_index[n]] for n in ('hip_l','knee_l','hip_r','knee_r')]),3).tolist()} qank={w.q[w.joint_index['ankle_l']]:.2f},{w.q[w.joint_index['ankle_r']]:.2f} hip x={o[0]:.3f} goal={wk.hip_goal[0]:.3f} cmd={getattr(wk,'hip_cmd_x',0):.3f} hipz={o[2]:.3f} rp=({r:+.2f},{p:+.2f}) arms={arms.tolist()} q_arm={np.round([w.q[j] for j in wk.arm_joints['l']+wk.arm_joints['r']],2).tolist()} tipz={wk.tip_point('l')[2]:.3f},{wk.tip_point('r')[2]:.3f}")
    res = wk.run(a.steps, max_time_s=150, on_tick=on_tick)
    print("RESULT", res.steps_completed, res.fell, res.fall_reason, res.fall_phase)

"""Probe 3: double support, sticks up; the legs command the hip to x targets (IK, pitch goal); where does it go?"""
import sys, math, numpy as np
sys.path.insert(0, "/work/main")
from config.loader import load_config, default_config_path, with_overrides
from sim.world import World, StancePose
from sim.kinematics import Kinematics
from sim.actuation import Mode
from sim.model import EXO_JOINTS, ARM_JOINT_NAMES, leg_ik
from sim.sensors import rpy_from_matrix
REST_FROM_POSE = True
cfg0 = load_config(default_config_path())
def run(k, rest, targets, front=0.06, rear=-0.06, pitch_goal=0.1, hipz=0.90, ff=False):
    c = with_overrides(cfg0, {"sim.mode": "full3d", "sim.model.joints.ankle.stiffness_nm_rad": k, "sim.model.joints.ankle.rest_rad": rest}).sim
    with World(c) as w:
        w.place(StancePose(foot_x_m=(front, rear), tip_xy_m=((0.3, 0.3), (0.3, -0.3)), trunk_pitch_rad=pitch_goal, hip_x_m=0.0, knee_rad=0.45))
        kin = Kinematics(w); b = w.body
        q0 = w.q.copy()
        hipz = float(w.link_frame("trunk")[0][2])
        if REST_FROM_POSE:
            n_exo, n_arm = 4, 6
            for i, nm in enumerate(("ankle_l", "ankle_r")):
                w._law[1, n_exo + n_arm + i] = w.q[w.joint_index[nm]]
            print("   rest set to", [round(float(w.q[w.joint_index[nm]]), 3) for nm in ("ankle_l", "ankle_r")])
        hx = 0.0
        out = []
        for tx in targets:
            for step in range(int(2.0 * 250)):
                if step % 5 == 0:
                    hx += float(np.clip(tx - hx, -0.002, 0.002))
                    kin.update(); g = kin.gravity_torques()
                    for i, (n, fx) in enumerate(zip(EXO_JOINTS, (front, front, rear, rear))):
                        j = w.joint_index[n]
                        h, kn = leg_ik(np.array([fx - hx, b.ankle_height_m - hipz]), b.thigh_m, b.shank_m)
                        tgt = (h + pitch_goal) if n.startswith("hip") else kn
                        w.exo.command(i, Mode.TRACK, tgt, 0.0, 0.0)
                    tg = [q0[w.joint_index[n]] + (0.8 if n.startswith("elbow") else 0.0) for n in ARM_JOINT_NAMES]
                    w.arms.track(np.array(tg), np.array([g[w.joint_index[n]] for n in ARM_JOINT_NAMES]))
                w.step()
            kin.update(); o, R = w.link_frame("trunk")
            fl, fr = w.contact_normal_force("foot_l"), w.contact_normal_force("foot_r")
            out.append(f"target {tx:+.3f}: hip {o[0]:+.3f} com {kin.com[0]:+.3f} pitch {rpy_from_matrix(R)[1]:+.3f} hipz {o[2]:.3f} feet {fl:.0f},{fr:.0f} qank {w.q[w.joint_index['ankle_l']]:.2f},{w.q[w.joint_index['ankle_r']]:.2f}")
        return out
for k, rest in ((100, 0.15), (250, 0.15), (400, 0.15), (800, 0.15)):
    print("== k", k, "rest", rest)
    for line in run(k, rest, [0.0, 0.02, 0.04, 0.06, 0.02, -0.02, -0.04, 0.0]): print("  ", line)

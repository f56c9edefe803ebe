import sys, math, numpy as np
sys.path.insert(0, "/work/main")
from config.loader import load_config, default_config_path, with_overrides
from sim.world import World, StancePose
from sim.kinematics import Kinematics
from sim.actuation import Mode
from sim.model import EXO_JOINTS, ARM_JOINT_NAMES
cfg0 = load_config(default_config_path())
def run(k, rest, hip_x, front=0.15, t_end=3.0, knee=0.15, lift=True):
    c = with_overrides(cfg0, {"sim.mode": "full3d", "sim.model.joints.ankle.stiffness_nm_rad": k, "sim.model.joints.ankle.rest_rad": rest}).sim
    with World(c) as w:
        w.place(StancePose(foot_x_m=(front, 0.0), tip_xy_m=((0.5, 0.3), (0.5, -0.3)), trunk_pitch_rad=0.1, hip_x_m=hip_x, knee_rad=knee))
        kin = Kinematics(w)
        q0 = w.q.copy()
        out = []
        for step in range(int(t_end * 250)):
            if step % 5 == 0:
                kin.update()
                g = kin.gravity_torques()
                for i, n in enumerate(EXO_JOINTS):
                    j = w.joint_index[n]
                    w.exo.command(i, Mode.TRACK, q0[j], 0.0, 0.0)
                tg = []
                for i, n in enumerate(ARM_JOINT_NAMES):
                    j = w.joint_index[n]
                    tg.append(q0[j] + (0.6 if (lift and n.startswith("elbow")) else 0.0))
                w.arms.track(np.array(tg), np.array([g[w.joint_index[n]] for n in ARM_JOINT_NAMES]))
            w.step()
            if step % 125 == 124:
                kin.update()
                com = kin.com
                af = kin.joint_origin[w.joint_index["ankle_l"]]; ar = kin.joint_origin[w.joint_index["ankle_r"]]
                fl, fr = w.contact_normal_force("foot_l"), w.contact_normal_force("foot_r")
                tl, tr = w.contact_normal_force("forearm_l"), w.contact_normal_force("forearm_r")
                out.append(f"t={step/250:.1f} com-front={com[0]-af[0]:+.3f} com-rear={com[0]-ar[0]:+.3f} feet={fl:.0f},{fr:.0f} tips={tl:.0f},{tr:.0f} qank={w.q[w.joint_index['ankle_l']]:.2f},{w.q[w.joint_index['ankle_r']]:.2f} hipz={w.link_frame('trunk')[0][2]:.3f}")
        return out
for k, rest in ((100, 0.15), (400, 0.15), (400, 0.05)):
    for hip_x in (0.05, 0.12, 0.18, 0.24):
        print("== k", k, "rest", rest, "hip_x", hip_x)
        for line in run(k, rest, hip_x)[::2]: print("  ", line)

"""Wrap GaitPlanner.double_support to print why a lean is not ready."""
import sys
sys.path.insert(0, "/work/i43")
import numpy as np
import controller.gait as G
orig = G.GaitPlanner.double_support
cnt = [0]
def ds(self, est, m, swing_leg):
    r = orig(self, est, m, swing_leg)
    cnt[0] += 1
    if r.part == "lean" and cnt[0] % 25 == 0:
        p = self.p; stance = 1 - swing_leg
        com_x = self._com_x
        tips_x = float(np.mean(est.tips[:, 0]) - est.ankles[stance][0])
        share = min(1.0, 2.0 * p.comfort_stick_n / (self.loads.total_kg * 9.81))
        front = float(np.max(est.ankles[:, 0]))
        print(f"   DS com_x={com_x:.3f} limit={share*tips_x:.3f} goal={self.goal_x:.3f} still={self._lean_still_s:.2f} moved={self._lean_moved} "
              f"ahead={np.round(est.tips[:,0]-front,3).tolist()} feet={np.round(m.heel_force_n+m.toe_force_n,0).tolist()} sticks={np.round(self.sticks.force_n,0).tolist()} raw={np.round(self.sticks.raw_n,0).tolist()} ready={r.ready}")
    return r
G.GaitPlanner.double_support = ds
import runpy
runpy.run_path("/tmp/probe/ctr.py", run_name="__main__")

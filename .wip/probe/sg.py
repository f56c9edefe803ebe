import sys
sys.path.insert(0, "/work/i43")
import sim.patient as P
orig = P.Patient._stick_goal
def sg(self, side, start):
    g = orig(self, side, start)
    print(f"t={self.world.t if hasattr(self.world,'t') else 0:.1f} goal {side} start={start[0]:.3f} goal={g[0]:.3f} front={self.front_foot()} ankles={[round(float(self.ankle_xy(s)[0]),3) for s in 'lr']} shoulder={self.shoulder(side)[0]:.3f} com={self.kin.com[0]:.3f} clamps={self.clamps}")
    return g
P.Patient._stick_goal = sg
import runpy
sys.argv = ["ctr.py", "--config", "/tmp/s7/e1.yaml", "--seed", "7", "--cycles", "10", "--every", "100000"]
runpy.run_path("/tmp/probe/ctr.py", run_name="__main__")

"""sub.py WORKTREE CFG "GAITS" N [key=value ...]: a subset of the full3d compare (paired seeds).
GAITS: e.g. "a 0.10 0.20" (a = the configured theta). Prints per gait: full, falls(within 6), both-sticks N, X stats."""
import sys, json, statistics as st, concurrent.futures as cf
wt, cfgp, gaits, n = sys.argv[1], sys.argv[2], sys.argv[3].split(), int(sys.argv[4])
sys.path.insert(0, wt)
from config.loader import load_config
from tools.experiment.runner import WalkJob, run_walk
from tools.experiment.learn import walk_seed
import os
if os.environ.get('OPTC'):
    import optc
if os.environ.get("NOCAP"):
    import sim.patient as P
    from sim.linalg import clamp as _clamp
    def _lean_goal(self):
        g = self.g
        rear, front = self.swing_span(self.front_foot())
        return rear + _clamp(self.plan.intention.lean_x, g.lean_x_min, g.lean_x_max) * (front - rear)
    P.Patient._lean_goal = _lean_goal
cfg = load_config(cfgp if cfgp != "-" else wt + "/config/default.yaml")
theta = tuple(cfg.controller.compensation.theta) if hasattr(cfg.controller.compensation, "theta") else None
def job(g, s):
    if g == "a":
        c = cfg.controller.compensation
        return WalkJob(seed=s, cycles=10, mode="full3d", theta=(c.alpha, c.xhat_com))
    return WalkJob(seed=s, cycles=10, mode="full3d", fixed_m=float(g))
def one(args):
    g, s = args
    return g, run_walk(cfg, job(g, s))
seeds = [walk_seed(0, 100, i) for i in range(n)]
res = {}
with cf.ProcessPoolExecutor(2) as ex:
    for g, r in ex.map(one, [(g, s) for g in gaits for s in seeds]):
        res.setdefault(g, []).append(r)
allx = []
for g, rs in res.items():
    full = sum(r["complete"] for r in rs)
    early = sum((not r["complete"]) and r["cycles_completed"] < 6 for r in rs)
    f = [2 * r["mean_stick_force_n"] for r in rs if r.get("mean_stick_force_n")]
    xs = [x for r in rs for x in r["step_x_ratio"]]; allx += xs
    ends = [f'{r["end"][:40]}@{r["cycles_completed"]}' for r in rs if not r["complete"]]
    print(f"{g}: full {full}/{len(rs)} (fail<6 cyc {early}); X med {st.median(xs):.3f} sd {st.pstdev(xs):.3f}; both {st.mean(f):.0f} N; ends {ends}")
    res[g] = rs
json.dump(res, open("/tmp/probe/sub_last.json", "w"))
allx.sort(); q = lambda p: allx[int(p * (len(allx) - 1))]
print(f"all X median {q(.5):.3f} sd {st.pstdev(allx):.3f} p10-p90 {q(.1):.3f}-{q(.9):.3f} range {q(.9)-q(.1):.3f}")

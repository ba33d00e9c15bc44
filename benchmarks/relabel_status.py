"""A relabelling's progress, and what the ladder made of the source's refusals (issue 54).

    python benchmarks/relabel_status.py [SOURCE NEW]   (default data/capability_episodes and
                                                        data/capability_episodes_ladder)

Of the episodes walked again so far (qz capability relabel), each mission the source had refused:
still refused, planned on a rung and walked, or planned and failed walking (with the reason).
"""
import collections
import sys

import numpy as np

from qz_drake.capability.dataset import load_records
from qz_drake.capability.relabel import _unchanged

SOURCE, NEW = (sys.argv[1], sys.argv[2]) if len(sys.argv) > 2 else ("data/capability_episodes", "data/capability_episodes_ladder")
src, _ = load_records(SOURCE)
new, m = load_records(NEW)
key = lambda a, i: (int(a["index"][i]), int(a["heading_sample"][i]))
srcmap = {key(src, i): i for i in range(len(src["index"]))}
newmap = {key(new, i): i for i in range(len(new["index"]))}
refused_src = [k for k, i in srcmap.items() if src["status"][i] == "executed" and not src["blc_success"][i]]
same, others = _unchanged(src)
done_new = set(new["index"].tolist())
rerun_done = others & done_new
c = collections.Counter()
for k in refused_src:
    if k[0] not in rerun_done:
        continue
    j = newmap.get(k)
    if j is None:
        c["missing"] += 1
    elif not new["blc_success"][j]:
        c["still refused"] += 1
    elif new["success"][j]:
        c["planned on a rung, walked"] += 1
    else:
        c[f"planned, failed: {new['reason'][j]}"] += 1
ex = new["status"] == "executed"
print(f"episodes: {len(done_new)} of {len(set(src['index'].tolist()))} ({len(same)} copied, {len(rerun_done)} of {len(others)} walked again)")
print(f"records {len(new['index'])}, executed {int(ex.sum())}, walked {int((ex & new['success']).sum())}, no plan {int((ex & ~new['blc_success']).sum())}, failed {int((ex & new['blc_success'] & ~new['success']).sum())}")
print("the source's refusals in the re-walked episodes:", dict(c))
sub = np.isin(src["index"], list(rerun_done))
exs = (src["status"] == "executed") & sub
subn = np.isin(new["index"], list(rerun_done))
exn = (new["status"] == "executed") & subn
print(f"those episodes: source {int(exs.sum())} missions, no plan {int((exs & ~src['blc_success']).sum())}; now {int(exn.sum())} missions, no plan {int((exn & ~new['blc_success']).sum())}, failed {int((exn & new['blc_success'] & ~new['success']).sum())}")

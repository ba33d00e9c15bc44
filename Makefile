# qz_drake: `make demo` runs the main job, `make test` runs the tests. Both create .venv first.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.qz_installed
OUT ?= out/demo
# `make test` (and CI) leaves out the tests marked slow, so that the suite fits CI's 20 minutes
# on 2 cores; `make test-all` runs them too (about 20 minutes on 2 cores).
PYTEST_MARK ?= not slow
PYTEST_ARGS ?=
# pytest-xdist's worker processes, one per core of the 2-core machine (most tests are one
# process on one core), an idle one taking tests from the other's queue (worksteal: the suite's
# longest tests, notebooks of 20-30 s, do not leave one core idle at the end);
# PYTEST_WORKERS=0 runs every test in pytest's own process.
PYTEST_WORKERS ?= 2

.PHONY: setup demo test test-all test-fast bench urdf clean collect fig9

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# The CPU build of torch (a bare `torch` would pull a multi-GB CUDA build).
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

setup: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/qz demo --out $(OUT)

test: $(STAMP)
	$(PY) -m pytest -q -n $(PYTEST_WORKERS) --dist worksteal $(if $(PYTEST_MARK),-m "$(PYTEST_MARK)") $(PYTEST_ARGS)

# One process: the slow tests include walks at real time across processes, which a second
# test beside them would slow.
test-all: $(STAMP)
	$(PY) -m pytest -q $(PYTEST_ARGS)

test-fast: $(STAMP)
	$(PY) -m pytest -q -n $(PYTEST_WORKERS) --dist worksteal -m "not slow" $(PYTEST_ARGS)

bench: $(STAMP)
	# pyastar2d, the C++ A* that `qz bench astar` compares against.
	$(PY) -m pip install -q -e '.[bench]'
	$(VENV)/bin/qz bench all --json

# The capability dataset, chained missions from where the last one ended (hours; resumable):
# re-certify the folder if fingerprinted code changed without changing behaviour (a no-op
# otherwise; it stops here if behaviour changed), then continue the collection, one progress
# line every 5 minutes. The committed dataset stopped at 669 of these 1200 scenes (its README);
# it was labelled with Eq. 7 in the controller at 2 ms, as every dataset before issue 53's
# defaults, so its collection goes on so.
collect: $(STAMP)
	$(VENV)/bin/qz capability recertify data/capability_episodes --workers 2
	nice -n 19 $(VENV)/bin/qz capability collect --out data/capability_episodes --protocol episodes --seed 37 \
		--scenes 1200 --workers 2 --shard-size 100 --json --log-every 300 --control-mode torque --time-step 0.002

# Paper 000 Fig. 9 from a capability dataset (hours; every step resumes where it stopped): the
# boosted capability model trained on DATASET (LEARNER=cnn: the paper's 18 networks), A* and
# CapPlanner tuned on the tuning worlds (seeds 1000+) with the walks' BLC ladder and route check
# (FIG9_WALK) that both planners then walk the experiment with, the 900 medium and hard walks of
# the experiment (50 tasks per terrain and difficulty from seed FIG9_SEED: 100-149, worlds no one
# had looked at when issue 55 chose them; 50-99 are kept for checks outside the project), then the
# 450 simple ones, then its tables. Everything goes under FIG9.
DATASET ?= data/capability_episodes
LEARNER ?= boosted
FIG9 ?= out/paper_fig9
WORKERS ?= 2
FIG9_SEED ?= 100
FIG9_WALK ?= --route-check 2 --blc-ladder cycles+1,split,split+1,cycles+2
CAPPLANNER_GRID ?= --failure-rewards -50,-100,-200 --plan-failure-risks 1 --mission-lengths 1.42,2 --merge-thresholds 0.95
fig9: $(STAMP)
	test -f $(FIG9)/model/report.json || \
		$(VENV)/bin/qz capability train --dataset $(DATASET) --out $(FIG9)/model --learner $(LEARNER)
	nice -n 19 $(VENV)/bin/qz experiment tune-astar --out $(FIG9)/astar_tuning --workers $(WORKERS) $(FIG9_WALK)
	nice -n 19 $(VENV)/bin/qz experiment tune-capplanner --model $(FIG9)/model --out $(FIG9)/capplanner_tuning \
		--workers $(WORKERS) $(FIG9_WALK) $(CAPPLANNER_GRID)
	for difficulties in medium,hard simple,medium,hard; do \
		nice -n 19 $(VENV)/bin/qz experiment capplanner-vs-astar --model $(FIG9)/model \
			--astar-tuning $(FIG9)/astar_tuning --capplanner-tuning $(FIG9)/capplanner_tuning \
			--out $(FIG9)/experiment --workers $(WORKERS) --first-seed $(FIG9_SEED) \
			--difficulties $$difficulties --recordings 0 $(FIG9_WALK) || exit $$?; \
	done
	$(VENV)/bin/qz experiment report $(FIG9)/experiment --predict

urdf: $(STAMP)
	$(PY) scripts/make_urdf.py

clean:
	rm -rf out .pytest_cache

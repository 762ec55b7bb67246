# Two commands a user needs (see README):  make demo   and   make test
# `make setup` is idempotent: it reinstalls only when requirements change and rebuilds
# the colcon workspace only when a package's metadata or data files change (sources are
# symlinked, so editing Python needs no rebuild).
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
WS := ros2_ws
PKGS := $(sort $(dir $(wildcard $(WS)/src/*/package.xml)))
# Files whose change needs a colcon rebuild (metadata, entry points, installed data).
PKG_META := $(wildcard $(WS)/src/*/package.xml $(WS)/src/*/setup.py $(WS)/src/*/setup.cfg \
             $(WS)/src/*/resource/* $(WS)/src/*/config/*)
BAG ?= bags/quick
# Playback rate of the demo (the quick bag spans ~30 min of rover time).
RATE ?= 5
# Run directory of the demo: out/<bag>/$(RUN_ID)/ (evaluated right after the run).
ifndef RUN_ID
RUN_ID := $(shell date +%Y%m%d-%H%M%S)
endif
RUN_ENV := source ./env.sh &&

.PHONY: setup sysdeps test demo bench lint clean training-bags orbital-training-worlds \
        orbital-model rover-model models
setup: sysdeps $(VENV)/.installed $(WS)/install/.built

# Debian packages beyond PyPI (Mesa EGL for the simulator's renderer); a no-op when present.
sysdeps:
	@bash scripts/install-system-deps.sh

$(VENV)/.installed: requirements.txt
	@test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	@echo "[setup] installing pinned requirements into $(VENV) (first time: about a minute)"
	$(VENV)/bin/python -m pip install --quiet --disable-pip-version-check -r requirements.txt
	@touch $@

$(WS)/install/.built: $(VENV)/.installed $(PKG_META)
	@echo "[setup] colcon build --symlink-install ($(words $(PKGS)) packages)"
	@source $(VENV)/bin/activate && export AMENT_PREFIX_PATH=$$VIRTUAL_ENV && \
	  cd $(WS) && colcon --log-base log build --symlink-install --event-handlers console_cohesion- \
	  > build.log 2>&1 || { tail -40 build.log; echo "[setup] colcon build failed, see $(WS)/build.log"; exit 1; }
	@touch $@

test: setup
	$(RUN_ENV) python -m pytest $(PYTEST_ARGS)

# Every benchmark the README and docs quote, into bench/results/current/ at one commit
# (bench/run_all.py): TIER=quick (default) on the demo bag, under an hour on 2 cores;
# TIER=full also on atacama_1km seeds 1-3 (generated when missing) with the committed
# table sizes. BENCH_ARGS=--dry-run prints the commands.
TIER ?= quick
bench: setup
	$(RUN_ENV) python bench/run_all.py --tier $(TIER) $(BENCH_ARGS)

lint: setup
	$(RUN_ENV) ruff check ros2_ws/src tests bench

demo: setup
	@if [ ! -d "$(BAG)/rosbag" ]; then \
	  $(RUN_ENV) command -v atacama_sim >/dev/null || { \
	    echo "demo: cannot generate $(BAG): the atacama_sim generator is not built"; exit 2; }; \
	  $(RUN_ENV) atacama_sim generate --preset quick --seed 1 --out $(BAG); fi
	@# The GN of the bag's orbital image (once per bag), for gn_server and the matcher.
	@if [ ! -f "$(BAG)/gn.geojson" ] && [ -f "$(BAG)/orbital.tif" ]; then \
	  $(RUN_ENV) orbital_gn prepare $(BAG)/orbital.tif --out $(BAG)/gn.geojson \
	    --preview $(BAG)/gn.png; fi
	@# A degraded run (exit 3: a node published nothing, restarted, ...) is still
	@# evaluated, its reasons printed first; make then exits with the run's status.
	@rc=0; $(RUN_ENV) globloc run $(BAG) --out out --rate $(RATE) --run-id $(RUN_ID) || rc=$$?; \
	  if [ $$rc -eq 0 ] || [ $$rc -eq 3 ]; then \
	    $(RUN_ENV) globloc eval out/$(notdir $(patsubst %/,%,$(BAG)))/$(RUN_ID) || exit $$?; fi; \
	  exit $$rc

# The committed classifier models are trained on bags of the training seeds (never an
# evaluation seed); the bags are generated first when missing (about 6 min each).
TRAIN_DIR ?= bags
TRAIN_SEEDS ?= 101 102
TRAIN_BAGS := $(foreach s,$(TRAIN_SEEDS),$(TRAIN_DIR)/train_quick_s$(s))
training-bags: setup
	@for s in $(TRAIN_SEEDS); do \
	  if [ ! -d "$(TRAIN_DIR)/train_quick_s$$s/rosbag" ]; then \
	    $(RUN_ENV) atacama_sim generate --preset quick --seed $$s \
	      --out $(TRAIN_DIR)/train_quick_s$$s || exit 1; fi; done

# The orbital classifiers also learn from landing-site-size worlds: atacama_1km worlds of
# training seeds, orbital products only (no traverse: about 75 s each). Six of them hold
# about 900 rocks and 250 outcrops, against 140 and 50 in the two quick training bags.
ORBITAL_TRAIN_SEEDS ?= 101 102 103 104 105 106
ORBITAL_TRAIN_WORLDS := $(foreach s,$(ORBITAL_TRAIN_SEEDS),$(TRAIN_DIR)/train_orbital_1km_s$(s))
orbital-training-worlds: setup
	@for s in $(ORBITAL_TRAIN_SEEDS); do \
	  if [ ! -f "$(TRAIN_DIR)/train_orbital_1km_s$$s/world.yaml" ]; then \
	    $(RUN_ENV) atacama_sim generate --preset atacama_1km --seed $$s --orbital-only \
	      --no-progress --out $(TRAIN_DIR)/train_orbital_1km_s$$s || exit 1; fi; done

# Re-train the committed orbital classifiers (Rock Orbital, Outcrop Orbital): the default
# (sun_aware recipe) and the one prepare falls back to when a raster's sun direction is
# unknown (no_sun recipe).
ORBITAL_MODEL := $(WS)/src/orbital_gn/orbital_gn/models/orbital_default.npz
ORBITAL_MODEL_NO_SUN := $(WS)/src/orbital_gn/orbital_gn/models/orbital_no_sun.npz
orbital-model: training-bags orbital-training-worlds
	$(RUN_ENV) orbital_gn train $(TRAIN_BAGS) $(ORBITAL_TRAIN_WORLDS) --recipe sun_aware \
	  --out $(ORBITAL_MODEL)
	$(RUN_ENV) orbital_gn train $(TRAIN_BAGS) $(ORBITAL_TRAIN_WORLDS) --recipe no_sun \
	  --out $(ORBITAL_MODEL_NO_SUN)

# Re-train the committed rover model: the elevation_map method's two Rock Rovers, the
# far rocks', on every far track measured in the quick bags of ROVER_TRAIN_SEEDS (120-190
# per bag, 8-19 of them rocks), and the map rocks', on the map's rock regions of the same
# drives (3-17 per bag, 0-4 of them false); and the map outcrops' Outcrop Rover (PCA +
# kNN), on the map's outcrop regions of the same drives (5-14 per bag, 1-6 of them
# outcrops); about 4 min to generate and 3 min to run each bag, two at a time.
# `roi_detector train ... --method per_pair` trains the paper's per-pair Rock Rover and
# Outcrop Rover instead (not committed).
ROVER_MODEL := $(WS)/src/roi_detector/roi_detector/models/rover.npz
ROVER_TRAIN_SEEDS ?= 101 102 103 104 105 106 107 108 109 110 111 112
ROVER_TRAIN_BAGS := $(foreach s,$(ROVER_TRAIN_SEEDS),$(TRAIN_DIR)/train_quick_s$(s))
rover-model: setup
	@for s in $(ROVER_TRAIN_SEEDS); do \
	  if [ ! -d "$(TRAIN_DIR)/train_quick_s$$s/rosbag" ]; then \
	    $(RUN_ENV) atacama_sim generate --preset quick --seed $$s --no-progress \
	      --out $(TRAIN_DIR)/train_quick_s$$s || exit 1; fi; done
	$(RUN_ENV) roi_detector train $(ROVER_TRAIN_BAGS) --out $(ROVER_MODEL) --jobs 2

models: orbital-model rover-model

clean:
	rm -rf $(WS)/build $(WS)/install $(WS)/log $(WS)/build.log

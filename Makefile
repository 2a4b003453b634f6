# Two entry points: `make repro` (the benchmark's pipeline, dvc.yaml) and `make test` (the test
# suite); `make campaign` runs the study of discovery over hidden worlds (campaign/dvc.yaml).
# Each creates or reuses the virtual environment in .venv/.

SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
PIP := $(BIN)/python -m pip install --quiet --disable-pip-version-check -c constraints.txt

export PATH := $(abspath $(BIN)):$(PATH)
export DVC_NO_ANALYTICS := 1
export PYTHONHASHSEED := 0
# the numerical code paths every stage pins (src/nanosysid/numerics.py), for every command run here
PINNED := $(shell PYTHONPATH=src $(PYTHON) -m nanosysid.numerics)

.PHONY: venv test repro quick campaign readme params deps bench clean-venv toolchain toolchain-check toolchain-ready

venv: $(STAMP)

# uv installs the same pinned set from the same sources as pip in a fraction of its time: it is
# given pip's configured indexes and wheel folders, and pip's rule of the best version over all
# of them, and compiles the bytecode as pip does (else every process, every stage among them,
# compiles torch's sources again where PYTHONDONTWRITEBYTECODE is set). Where uv cannot be had,
# pip installs it all.
UV := uv==0.9.0
pipconf = $${PIP_$(2):-$$($(PYTHON) -m pip config get global.$(1) 2>/dev/null)}
UV_ENV = UV_FIND_LINKS="$$(echo $(call pipconf,find-links,FIND_LINKS) | tr ' ' ',')" \
	UV_EXTRA_INDEX_URL="$(call pipconf,extra-index-url,EXTRA_INDEX_URL)" \
	UV_DEFAULT_INDEX="$(call pipconf,index-url,INDEX_URL)" UV_INDEX_STRATEGY=unsafe-best-match
UV_PIP = $(BIN)/uv pip install --quiet --compile-bytecode --python $(BIN)/python -c constraints.txt

$(STAMP): requirements.txt constraints.txt pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	@if $(PIP) $(UV) 2>/dev/null; then \
	    export $(UV_ENV) && $(UV_PIP) -r requirements.txt && $(UV_PIP) --no-deps -e .; \
	else \
	    $(PIP) -r requirements.txt && $(PIP) --no-deps -e .; \
	fi
	@touch $@

# The ARM toolchain and QEMU for the mcu stages, installed through apt (as root) by
# `make toolchain`, which `make repro` and `make test` call where they are missing (without
# --no-install-recommends they take 3 GB). `export.mcu.enabled=false` runs the mcu stages
# without the toolchain, recording no microcontroller figures.
ARM_PACKAGES := gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm gcc libc6-dev
HAVE_TOOLCHAIN := command -v arm-none-eabi-gcc >/dev/null && command -v qemu-system-arm >/dev/null && command -v gcc >/dev/null
toolchain:
	@if $(HAVE_TOOLCHAIN); then \
	    :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "installing $(ARM_PACKAGES)"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $(ARM_PACKAGES) >/dev/null; \
	else \
	    echo "make toolchain: as root, apt-get install --no-install-recommends $(ARM_PACKAGES)"; exit 1; \
	fi

# `make test` installs the toolchain where it can (root, apt, within 5 minutes), so that the mcu
# tests run; where it cannot, they are skipped, with a note
toolchain-check:
	@if $(HAVE_TOOLCHAIN); then \
	    :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "installing $(ARM_PACKAGES): the mcu tests compile the exported models for the STM32F405 and run them on QEMU"; \
	    timeout 300 $(MAKE) --no-print-directory toolchain || echo "the installation failed"; \
	fi
	@$(HAVE_TOOLCHAIN) || echo "note: no ARM toolchain or QEMU: the mcu tests are skipped and the mcu stages need \
	\`make toolchain\` (as root) or export.mcu.enabled=false"

# `make repro` has what its mcu stages need before any stage runs: the toolchain installed where it
# can be (root, apt); where it cannot, it stops at once with what to do, unless the configuration
# switches the microcontroller off
MCU_ENABLED = $(shell $(BIN)/python -c "import yaml; print(str(yaml.safe_load(open('params.yaml'))['export']['mcu']['enabled']).lower())" 2>/dev/null)
toolchain-ready: params
	@if $(HAVE_TOOLCHAIN) || [ "$(MCU_ENABLED)" = false ]; then \
	    :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "installing $(ARM_PACKAGES): the mcu stages compile the exported models for the STM32F405 and run them on QEMU"; \
	    $(MAKE) --no-print-directory toolchain; \
	else \
	    echo "make repro: the mcu stages need the ARM toolchain and QEMU, which this machine lacks; run \`make toolchain\` as root, or set export.mcu.enabled: false in conf/config.yaml (no microcontroller figures)"; exit 1; \
	fi

# two workers, one test file each at a time: a file's module fixtures (the tiny pipeline, the DVC
# repository) are built once, and the two longest files start at once, beside each other. A third
# worker costs more CPU than it fills idle time (fresh clone: 1,112 s against 955 s with two)
TEST_WORKERS ?= 2
test: $(STAMP) toolchain-check
	@$(BIN)/python -m compileall -q src stages tests >/dev/null  # bytecode the tests' many processes share
	env $(PINNED) $(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder

# DVC composes params.yaml from conf/ only on `dvc exp run`; compose it here too so an
# edit to conf/ is never silently ignored by `dvc repro`.
params: $(STAMP)
	$(BIN)/python -m nanosysid.config compose

# every pipeline's code stage and its stages' code deps, from the import graph (after an import changes)
deps: $(STAMP)
	$(BIN)/python -m nanosysid.depgraph write

# every stage of dvc.yaml, REPRO_JOBS at a time where the DAG allows (src/nanosysid/repro.py: the
# same outputs and dvc.lock as `dvc repro`), each stage's time into reports/repro.last.json (no
# tracked file changes); `make readme` records those times (reports/repro.json) and regenerates
# the README's sections from the recorded outputs
REPRO_JOBS ?= 2
repro: params toolchain-ready
	env $(PINNED) $(BIN)/python -m nanosysid.repro --jobs $(REPRO_JOBS) --out reports/repro.last.json

# a first look in a few minutes: the whole chain, the campaign's one world included (beside the
# benchmark's stages, in one schedule), on short simulated flights with two epochs per learned model (conf/profile/quick.yaml), the rig's
# pipeline left out; not the benchmark's figures (the report says so at its top). `make repro`
# composes the benchmark's settings again; the run cache gives back what it already computed.
quick: toolchain-ready
	$(BIN)/python -m nanosysid.config compose profile=quick
	env $(PINNED) $(BIN)/python -m nanosysid.repro --jobs $(REPRO_JOBS) --skip-rig --pipeline dvc.yaml \
	    --pipeline campaign/dvc.yaml --out reports/repro.quick.json

# the campaign's pipeline (campaign/dvc.yaml and its own lock): discovery judged over hidden
# worlds, a study of the method that the benchmark's results do not need; its worlds go out
# through the launcher (conf/launcher/), so one stage at a time
campaign: params
	env $(PINNED) $(BIN)/python -m nanosysid.repro --pipeline campaign/dvc.yaml --jobs 1 \
	    --out reports/campaign-repro.last.json

# make repro's last record is kept in reports/repro.json for a run of both data sources, in
# reports/repro-sim.json for one without the real flights (the simulated world's pipeline alone)
readme: $(STAMP)
	@if [ -f reports/campaign-repro.last.json ]; then cp reports/campaign-repro.last.json reports/campaign-repro.json; fi
	$(BIN)/python -m nanosysid.report.readme --keep reports/repro.last.json \
	    --sections headline start results rig physics bench campaign

# every benchmark's figures into reports/bench.json, and from there into the README;
# `make bench NAMES="simulate_batch discover_speed"` reruns only those
bench: $(STAMP)
	env $(PINNED) PYTHONPATH=$(CURDIR) $(BIN)/python benchmarks/run.py $(NAMES)
	$(BIN)/python -m nanosysid.report.readme --sections bench start

clean-venv:
	rm -rf $(VENV)

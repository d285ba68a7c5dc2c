# morphshell: the front door.
#
#   make shape=petal        design, program, render, simulate and report build/petal/
#   make test               the whole test suite
#   make bench              benchmarks -> build/bench/*.json
#   make tolerance shape=petal [SAMPLES=64]   Monte Carlo tolerance analysis (Dask)
#   make sweep SPEC=file.toml                 build and tabulate design variants (Dask)
#   make mechtest shape=mechtest              SI Note 6's virtual mechanical tests
#   make coupon [OUT=dir]                     the printable timing coupon (docs/coupon.md)
#   make scad-params        regenerate scad/params.scad from pysolver/params/
#   make lock               re-resolve uv.lock (every package to its newest allowed release)
#
# The first call creates .venv and installs exactly the versions pinned in uv.lock (with
# uv, itself pinned and installed from PyPI into .uv/); Debian packages that are missing are
# installed with apt-get when running as root (otherwise the exact sudo line is printed).
# Re-running is fast when nothing changed.

SHELL      := /bin/bash
shape      ?= petal
SURFACE    ?=
MATERIAL   ?=
DATA       ?=
VERTICES   ?=
TIME       ?=
TIMEFILE   ?=
JOBS       ?=
ARGS       ?=
SAMPLES    ?=
SCHEDULER  ?=
WORKERS    ?=
SPEC       ?=
PYTHON     ?= python3
VENV       := .venv
PY         := $(VENV)/bin/python
STAMP      := $(VENV)/.installed
UV_VERSION := 0.13.9
UV         := .uv/bin/uv
APT_PKGS   := openscad libsuitesparse-dev libopenblas0-pthread libegl1 libegl-mesa0 libgl1-mesa-dri \
              chromium chromium-driver

export OMP_THREAD_LIMIT ?= 1
export VTK_DEFAULT_OPENGL_WINDOW ?= vtkEGLRenderWindow
export PYTHONDONTWRITEBYTECODE := 1

# User values reach the shell only through the environment, quoted ("$$MS_TIME"), never
# pasted into a recipe: a quote or $(...) in TIME, a path or ARGS is text, not a command.
# `override X := $(value X)` also stops make itself from expanding $(...) in them.
USER_VARS  := shape SURFACE MATERIAL DATA VERTICES TIME TIMEFILE REFINE JOBS ARGS OUT \
              SAMPLES SCHEDULER WORKERS SPEC
$(foreach v,$(USER_VARS),$(eval override $(v) := $$(value $(v))))
# Each of them reaches the recipes as MS_<NAME> (shape and SURFACE together as MS_SOURCE).
# (The eval expands $(X) once, as `:=` does: the value stays text.)
export MS_SOURCE   := $(if $(SURFACE),$(SURFACE),$(shape))
$(foreach v,$(filter-out shape SURFACE,$(USER_VARS)),$(eval export MS_$(v) := $$($(v))))
unexport $(USER_VARS)

# Options from the variables above, expanded by the shell (set -f: no globbing of ARGS,
# which is split into words on spaces).
DESIGN_OPTS := $${MS_MATERIAL:+--material "$$MS_MATERIAL"} \
              $${MS_VERTICES:+--vertices "$$MS_VERTICES"} \
              $${MS_TIME:+--time "$$MS_TIME"} $${MS_TIMEFILE:+--time-file "$$MS_TIMEFILE"} \
              $${MS_REFINE:+--refine "$$MS_REFINE"}
BUILD_OPTS := $(DESIGN_OPTS) $${MS_JOBS:+--jobs "$$MS_JOBS"} $$MS_ARGS
# The build folder's name, as pysolver.build.shape_name gives it (a mesh file's stem, else the
# shape as given), set by the shell as MS_NAME: make's own $(basename) and $(notdir) would split
# a path with spaces into words and cut "dome:size=1.5" at its dot.
SHAPE_NAME := MS_NAME="$$MS_SOURCE"; if [ -f "$$MS_NAME" ]; then MS_NAME="$${MS_NAME\#\#*/}"; \
              MS_NAME="$${MS_NAME%.*}"; fi;
RUN        := set -f; $(SHAPE_NAME)
DASK_OPTS  := $${MS_SCHEDULER:+--scheduler "$$MS_SCHEDULER"} \
              $${MS_WORKERS:+--workers "$$MS_WORKERS"}

.PHONY: all build design sim report test bench clean material membrane-model specimens \
        system-deps venv lint shapes studio studio-shots tolerance sweep scad-params lock \
        mechtest coupon

all: build

build: $(STAMP)
	@$(RUN) $(PY) -m pysolver.cli build "$$MS_SOURCE" $(BUILD_OPTS)

design: $(STAMP)
	@$(RUN) $(PY) -m pysolver.cli build "$$MS_SOURCE" --no-render --no-sim $(BUILD_OPTS)

sim: $(STAMP)
	@$(RUN) $(PY) -m pysolver.cli build "$$MS_SOURCE" --no-render $(BUILD_OPTS)

report: $(STAMP)
	@$(RUN) $(PY) -m pysolver.cli report "build/$$MS_NAME"

# The design folder is built first (no STLs) when it is missing; ARGS go to 'tolerance'
# (e.g. ARGS="--relaxation --thickness-sd 0.03").
tolerance: $(STAMP)
	@$(RUN) test -f "build/$$MS_NAME/cells.csv" || \
	  $(PY) -m pysolver.cli build "$$MS_SOURCE" --no-render $(DESIGN_OPTS) || exit $$?; \
	$(PY) -m pysolver.cli tolerance "build/$$MS_NAME" $${MS_SAMPLES:+--samples "$$MS_SAMPLES"} \
	  $${MS_MATERIAL:+--material "$$MS_MATERIAL"} $(DASK_OPTS) $$MS_ARGS

sweep: $(STAMP)
	@$(RUN) test -n "$$MS_SPEC" || { echo 'usage: make sweep SPEC=file.toml'; exit 2; }; \
	$(PY) -m pysolver.cli sweep "$$MS_SPEC" $${MS_OUT:+--out "$$MS_OUT"} $(DASK_OPTS) $$MS_ARGS

# The timing coupon: STLs, coupon.csv to fill in and coupon.md (docs/coupon.md)
coupon: $(STAMP)
	@$(RUN) $(PY) -m pysolver.cli coupon $${MS_OUT:+--out "$$MS_OUT"} \
	  $${MS_MATERIAL:+--material "$$MS_MATERIAL"} $${MS_JOBS:+--jobs "$$MS_JOBS"} $$MS_ARGS

shapes: $(STAMP)
	$(PY) -m pysolver.cli shapes

# The browser front end on build/<shape> (built first when missing); ARGS e.g. "--port 8765".
studio: $(STAMP)
	@$(RUN) test -f "build/$$MS_NAME/sim/frames.npz" || \
	  (MS_ARGS=; $(PY) -m pysolver.cli build "$$MS_SOURCE" $(BUILD_OPTS)) || test $$? = 3; \
	$(PY) -m pysolver.cli studio "build/$$MS_NAME" $$MS_ARGS

# Screenshots of the studio (paint, a bad value, the run's progress, the results, the target
# ghost; a run on a copy of build/<shape>, which is not changed) and of the report: docs/img/
studio-shots: $(STAMP)
	@$(RUN) test -f "build/$$MS_NAME/report/index.html" || \
	  $(PY) -m pysolver.cli build "$$MS_SOURCE" $(BUILD_OPTS) || test $$? = 3; \
	$(PY) -m pysolver.studio.shots "build/$$MS_NAME" docs/img

# SI Note 6's virtual mechanical tests on build/<shape> (built first when missing, programmed
# like any build: docs/mechtest.md says why not with uniform 0.5 mm brackets); ARGS go to
# 'mechtest'
# (e.g. ARGS="--test stretch --test bend").
mechtest: $(STAMP)
	@$(RUN) test -f "build/$$MS_NAME/sim/frames.npz" || \
	  $(PY) -m pysolver.cli build "$$MS_SOURCE" --no-render $(DESIGN_OPTS) || \
	  { rc=$$?; [ $$rc = 3 ] || exit $$rc; }; \
	$(PY) -m pysolver.cli mechtest "build/$$MS_NAME" $$MS_ARGS

material: $(STAMP)
	@$(RUN) $(PY) -m pysolver.cli fit-material $${MS_DATA:+--data "$$MS_DATA"} \
	  $${MS_OUT:+--out "$$MS_OUT"} $$MS_ARGS

membrane-model: $(STAMP)
	$(PY) -m pysolver.cli fit-membrane

# scad/params.scad from pysolver/params/: one source for the unit-cell dimensions
scad-params: $(STAMP)
	$(PY) -m pysolver.render.scad_params

specimens: $(STAMP)
	@$(RUN) $(PY) -m pysolver.cli specimens $${MS_JOBS:+--jobs "$$MS_JOBS"}

test: $(STAMP)
	@$(RUN) $(PY) -m pytest -q -n 2 --dist loadfile --no-loadscope-reorder $$MS_ARGS

bench: $(STAMP)
	@$(RUN) $(PY) bench/run.py $$MS_ARGS

lint: $(STAMP)
	$(VENV)/bin/ruff check pysolver sim tests bench

clean:
	rm -rf build .pytest_cache .ruff_cache

venv: $(STAMP)

# Debian packages: installed when missing (as root), else the sudo line is printed.
system-deps:
	@missing=""; for p in $(APT_PKGS); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ]; then \
	    echo "Installing Debian packages:$$missing"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null || exit 1; \
	  else \
	    echo "Missing Debian packages:$$missing"; \
	    echo "Run:  sudo apt-get install -y$$missing"; \
	    exit 1; \
	  fi; \
	fi

# uv, pinned: the tool that installs the lock (a wheel from PyPI, into its own venv)
$(UV):
	@$(PYTHON) -m venv .uv && .uv/bin/python -m pip install -q "uv==$(UV_VERSION)"

# exactly uv.lock (--locked: refused, with the fix, when pyproject.toml changed since)
$(STAMP): pyproject.toml uv.lock | system-deps $(UV)
	@$(UV) sync --locked --extra dev --python "$(PYTHON)" --quiet || { \
	  echo "The install from uv.lock failed. If pyproject.toml changed, refresh the lock: make lock"; \
	  exit 1; }
	@touch $(STAMP)

lock: $(UV)
	$(UV) lock --upgrade --python "$(PYTHON)"

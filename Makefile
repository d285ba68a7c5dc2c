# morphshell: the front door.
#
#   make shape=petal        design, program, render, simulate and report build/petal/
#   make test               the whole test suite
#   make bench              benchmarks -> build/bench/*.json
#
# The first call creates .venv and installs the project; Debian packages that are
# missing are installed with apt-get when running as root (otherwise the exact
# sudo line is printed).  Re-running is fast when nothing changed.

SHELL      := /bin/bash
shape      ?= petal
SURFACE    ?=
MATERIAL   ?=
DATA       ?=
VERTICES   ?=
TIME       ?=
REFINE     ?= 1
JOBS       ?=
ARGS       ?=
PYTHON     ?= python3
VENV       := .venv
PY         := $(VENV)/bin/python
STAMP      := $(VENV)/.installed
APT_PKGS   := openscad libsuitesparse-dev libopenblas0-pthread libegl1 libegl-mesa0 libgl1-mesa-dri

export OMP_THREAD_LIMIT ?= 1
export VTK_DEFAULT_OPENGL_WINDOW ?= vtkEGLRenderWindow
export PYTHONDONTWRITEBYTECODE := 1

# A user mesh can be given as shape=path/to/mesh.obj or SURFACE=path/to/mesh.obj.
SOURCE     := $(if $(SURFACE),$(SURFACE),$(shape))
BUILD_OPTS := $(if $(MATERIAL),--material $(MATERIAL)) $(if $(VERTICES),--vertices $(VERTICES)) \
              $(if $(TIME),--time "$(TIME)") $(if $(REFINE),--refine $(REFINE)) \
              $(if $(JOBS),--jobs $(JOBS)) $(ARGS)

.PHONY: all build design sim report test bench clean material membrane-model specimens \
        system-deps venv lint shapes

all: build

build: $(STAMP)
	$(PY) -m pysolver.cli build "$(SOURCE)" $(BUILD_OPTS)

design: $(STAMP)
	$(PY) -m pysolver.cli build "$(SOURCE)" --no-render --no-sim $(BUILD_OPTS)

sim: $(STAMP)
	$(PY) -m pysolver.cli build "$(SOURCE)" --no-render $(BUILD_OPTS)

report: $(STAMP)
	$(PY) -m pysolver.cli report "build/$(notdir $(basename $(SOURCE)))"

shapes: $(STAMP)
	$(PY) -m pysolver.cli shapes

material: $(STAMP)
	$(PY) -m pysolver.cli fit-material $(if $(DATA),--data $(DATA)) $(if $(OUT),--out $(OUT)) $(ARGS)

membrane-model: $(STAMP)
	$(PY) -m pysolver.cli fit-membrane

specimens: $(STAMP)
	$(PY) -m pysolver.cli specimens $(if $(JOBS),--jobs $(JOBS))

test: $(STAMP)
	$(PY) -m pytest -q -n 2 --dist loadfile $(ARGS)

bench: $(STAMP)
	$(PY) bench/run.py $(ARGS)

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

$(STAMP): pyproject.toml | system-deps
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	@touch $(STAMP)

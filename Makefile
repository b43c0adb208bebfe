# Two entry points that work on a fresh machine with python3 and make:
#   make demo   - a whole simulated session (calibration + 45 trials) and its identification
#   make test   - the test suite
# Each creates .venv and installs what it needs on first use.

PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-$(shell cksum < pyproject.toml | cut -d' ' -f1)

.PHONY: demo test bench gui clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[gui,plot,serial,test,mujoco,nwb,study]'
	rm -f $(VENV)/.installed-*
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/nmsid run --backend sim --participant DEMO --outdir sessions

# One BLAS thread per process: the suite runs on two pytest workers over two cores, and
# small matrix operations get slower, not faster, with threads competing for them.
test: $(STAMP)
	QT_QPA_PLATFORM=offscreen OPENBLAS_NUM_THREADS=1 $(PY) -m pytest -q -n 2

bench: $(STAMP)
	QT_QPA_PLATFORM=offscreen OPENBLAS_NUM_THREADS=1 $(PY) bench/run.py

gui: $(STAMP)
	$(VENV)/bin/nmsid gui --backend sim

clean:
	rm -rf $(VENV) build *.egg-info

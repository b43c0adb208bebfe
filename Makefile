# A thin wrapper over dev.py, the one entry point (plain Python: Windows has no make).
#   make demo   = python3 dev.py demo   - a whole simulated session and its identification
#   make test   = python3 dev.py test   - the test suite (ARGS="tests/x.py" to choose)
#   make bench / make gui / make clean
# Each creates .venv and installs what it needs on first use (dev.py says how).

PYTHON ?= python3

.PHONY: demo test bench gui clean

demo test bench gui clean:
	$(PYTHON) dev.py $@ $(if $(ARGS),-- $(ARGS))

# make demo: set up, then run the main job on the bundled sample.
# make test: set up, then run the test suite.
VENV   := .venv
JNDS   := $(VENV)/bin/jnds
EXTRAS ?= train,render,dev,bench,cluster,video
comma  := ,
STAMP  := $(VENV)/.installed-$(subst $(comma),-,$(EXTRAS))

.PHONY: setup demo test lint dataset clean

setup: $(STAMP)

$(STAMP): pyproject.toml tools/setup.sh
	EXTRAS=$(EXTRAS) bash tools/setup.sh
	touch $@

# validate the bundled sample, then run the int8 pipeline on it with the packaged artifacts
# (the shipped checkpoint's, tools/package_artifacts.py): frames, run.json, the contact sheet
# and a video in out/run, its score and OIDN's, the per-stage timing table
demo: setup
	$(JNDS) validate samples/orbit-160x90
	$(JNDS) run --input samples/orbit-160x90 --output out/run --video

# lint and format first (ruff, configured in pyproject.toml); pytest exit code 5 (no tests
# collected) is a failure, not a pass
test: setup lint
	$(VENV)/bin/python -m pytest -q; rc=$$?; \
	if [ $$rc -eq 5 ]; then echo "make test: pytest collected no tests" >&2; exit 1; fi; exit $$rc

lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

dataset: setup
	$(JNDS) dataset --out data

clean:
	rm -rf out .pytest_cache

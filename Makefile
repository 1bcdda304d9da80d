# liquidtwin developer entry points. `make test` is what CI runs (.ci/run).
#
#   make venv    create/update .venv (torch first and alone, then requirements.lock, then
#                the four packages, editable); re-runs only when an install input changes
#   make test    venv + the whole test suite, on TEST_JOBS (2) pytest-xdist workers
#   make demo    venv + `liquidtwin demo`: server + viewer + a client streaming a bundled pour;
#                the viewer stays up until Ctrl-C (make demo ARGS=--no-wait to exit after)
#   make bench   venv + `liquidtwin bench` (extra flags: make bench ARGS="...")
#   make proto   regenerate proto/src/liquidtwin_proto/*_pb2.py[i] from the .proto files
#   make clean   remove build outputs and the install stamp (keeps .venv; rm -rf .venv for a full reset)

PYTHON3 ?= python3
TORCH_VERSION := 2.13.0
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
STAMP := $(VENV)/.liquidtwin-installed
PACKAGES := proto server client viewer
# Test workers (pytest-xdist, whole files per worker so module fixtures run once): server
# tests use one torch thread each, so 2 workers fill these 2 cores (make test TEST_JOBS=1: serial).
TEST_JOBS ?= 2
# Threads per test process, the processes the tests start included (servers, CLIs, bench
# scripts): a child on torch's default thread pool beside two busy workers oversubscribes the
# cores, and OpenMP's waiting threads then make it several times slower (the warp-gain CLI
# test: 119 s in CI, 21 s alone). Tests that need 2 threads set them explicitly.
TEST_THREADS ?= 1

# Changing any of these re-runs the install. wildcard: server/ may not have its build
# files yet, and a missing prerequisite must not break the other packages' installs.
INSTALL_INPUTS := requirements.lock \
	$(wildcard $(addsuffix /pyproject.toml,$(PACKAGES)) $(addsuffix /setup.py,$(PACKAGES))) \
	$(wildcard server/csrc/*.cpp server/csrc/*.h)

# Debian packages the test suite needs (installed by `make test` when missing): chromium
# drives the viewer test through Playwright (never `playwright install`).
APT_PACKAGES := chromium

.PHONY: venv test demo bench proto clean apt

venv: $(STAMP)

$(STAMP): $(INSTALL_INPUTS)
	test -x $(PY) || $(PYTHON3) -m venv $(VENV)
	$(PIP) install --upgrade pip
	$(PIP) install torch==$(TORCH_VERSION)
	$(PIP) install -r requirements.lock
	LIQUIDTWIN_REQUIRE_NATIVE=1 $(PIP) install --no-build-isolation $(addprefix -e ./,$(PACKAGES))
	touch $@

apt:
	@missing=""; \
	for p in $(APT_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
		sudo=""; [ "$$(id -u)" = 0 ] || sudo=sudo; \
		$$sudo apt-get update -qq && $$sudo apt-get install -y -qq $$missing; \
	fi

test: venv apt
	OMP_NUM_THREADS=$(TEST_THREADS) $(PY) -m pytest -q -n $(TEST_JOBS) --dist loadfile --durations=20 tests

demo: venv
	$(VENV)/bin/liquidtwin demo $(ARGS)

bench: venv
	$(VENV)/bin/liquidtwin bench $(ARGS)

proto:
	@test -x $(PY) || { echo "make proto: no $(PY); run 'make venv' first" >&2; exit 1; }
	$(PY) proto/generate.py

clean:
	rm -rf .pytest_cache $(STAMP) $(addsuffix /build,$(PACKAGES))
	find $(PACKAGES) tests -name __pycache__ -type d -prune -exec rm -rf {} +
	find $(PACKAGES) -name '*.egg-info' -type d -prune -exec rm -rf {} +
	find server -name '*.so' -type f -delete

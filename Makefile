# URSA: every target creates .venv first when it is missing (or when pyproject.toml changed).
PYTHON ?= $(shell command -v python3.11 || command -v python3.12 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
ARGS ?=
PYTEST_ARGS ?=

.PHONY: run test test-fast bench lint proto system-deps clean

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --upgrade pip wheel setuptools
	$(PY) -m pip install -e '.[dev]'
	@touch $(STAMP)

## run: the whole stack on this machine (default config); ARGS="--collectors 4 --preset tiny"
run: $(STAMP)
	$(PY) -m services.cli up $(ARGS)

## system-deps: Debian packages the tests use (headless chromium for the dashboard test)
system-deps:
	@command -v chromium >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    (apt-get update -qq || true) && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; \
	  else echo "chromium missing and cannot be installed here; the browser test will skip"; fi; }

## test: the whole suite, slow end-to-end tests included
test: $(STAMP) system-deps
	$(PY) -m pytest $(PYTEST_ARGS)

## test-fast: everything but the slow end-to-end tests
test-fast: $(STAMP)
	$(PY) -m pytest -m "not slow and not docker" $(PYTEST_ARGS)

## bench: every benchmark in quick mode
bench: $(STAMP)
	@for b in benchmarks/*.py; do echo "== $$b"; $(PY) $$b --quick || exit 1; done

## lint: ruff (lint and format) and mypy over the whole tree; CI runs it before the tests
lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/mypy ursa proto services tests benchmarks

## proto: regenerate proto/ursa_pb2.py(i) from proto/ursa.proto
proto: $(STAMP)
	$(PY) -m grpc_tools.protoc -Iproto --python_out=proto --pyi_out=proto proto/ursa.proto

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache

# ---- docker: the compose deployment (docs/deploy.md) -----------------------------------------
COMPOSE ?= $(shell docker compose version >/dev/null 2>&1 && echo "docker compose" || echo docker-compose)
COLLECTORS ?= 2

.PHONY: docker-base docker-build docker-lock docker-up docker-down docker-test

## docker-base: local Debian base image from this machine's apt sources (no registry needed)
docker-base:
	docker/build-base.sh

## docker-build: the URSA image (URSA_IMAGE, default ursa:latest) on the local base, from a wheelhouse
docker-build:
	docker/build.sh

## docker-lock: re-pin the image's transitive dependencies (docker/constraints.txt)
docker-lock: $(STAMP)
	$(PY) docker/deps.py lock

## docker-up: build, then the stack in containers; COLLECTORS=4 scales the collectors
docker-up: docker-build
	$(COMPOSE) up -d --scale collector=$(COLLECTORS)

## docker-down: stop the stack (the run-directory volume stays; `$(COMPOSE) down -v` drops it)
docker-down:
	$(COMPOSE) down

## docker-test: the compose deployment test (builds the image, ~15 min)
docker-test: $(STAMP)
	$(PY) -m pytest -m docker tests/integration/test_compose.py $(PYTEST_ARGS)

# Fine-pointing firmware workbench. Every target installs what it needs first.
PYTHON3 ?= python3
VENV    := .venv
PY      := $(VENV)/bin/python
MPY     := $(VENV)/bin/micropython
STAMP   := $(VENV)/.installed-stamp
NATMOD  := firmware/adcs/adcsk.mpy
PIL_ELF := build/pil/MICROBIT/firmware.elf
PIL_SRC := $(wildcard firmware/*.py firmware/hal/*.py firmware/adcs/*.py protocol/*.py protocol/spacecraft/*.py \
             tests/mp/pil_probe.py \
             tests/mp/pil_adcs_probe.py tests/mp/firmware_plant.py) firmware/adcs/native/adcsk.c tools/pil_build.py
OUT     ?= out

# Python's default, which some machines turn off: modules compiled once into __pycache__ (ignored by git), not
# again in each of the hundreds of processes the tests and runs start (0.35 s of each fps start here); pip
# installs without compiling and compileall compiles on every core
export PYTHONDONTWRITEBYTECODE :=

.PHONY: all install test check figures bench fuzz mpy natmod pil hil distfile calibrate protocol-doc consts clean system

all: test

$(STAMP): requirements.lock pyproject.toml emulator/spacecraft/_truth.c firmware/adcs/native/adcsk.c \
           firmware/adcs/native/adcsk_cpython.c
	test -x $(PY) || $(PYTHON3) -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check --no-compile -r requirements.lock
	$(PY) -m pip install -q --disable-pip-version-check --no-compile --no-deps -e .
	$(PY) -m compileall -q -j 0 $(VENV)/lib > /dev/null
	touch $@

install: $(STAMP)

# on every core (pytest-xdist; an idle worker takes tests queued for a busy one): under 5 minutes on 2 cores
test: $(STAMP) $(NATMOD) $(PIL_ELF)
	$(PY) -m compileall -q -j 0 protocol firmware emulator ground tools bench tests > /dev/null
	$(PY) -m pytest -n auto --dist worksteal

# the daily tier: everything but the end-to-end modules (tests/conftest.py), under 2 minutes
check: $(STAMP) $(NATMOD)
	$(PY) -m pytest -n auto --dist worksteal -m "not e2e"

bench: $(STAMP) mpy $(NATMOD)
	$(PY) -m bench.run

# The ADCS kernels as a MicroPython native module (tools/natmod_build.py). The targets that run the ADCS
# firmware build it when they can and run its Python forms when they cannot; `make natmod` insists.
$(NATMOD): firmware/adcs/native/adcsk.c firmware/adcs/native/Makefile tools/natmod_build.py $(STAMP)
	$(PY) -m tools.natmod_build --optional

natmod: $(STAMP)
	$(PY) -m tools.natmod_build

# Processor in the loop (tools/pil_build.py): the controller frozen into MicroPython's qemu port for a Cortex-M0
# (QEMU's microbit machine), a 32 KB board and a 256 KB lab board, and the lean ADCS with its C kernels for a
# Cortex-M7 with an FPU (QEMU's mps2-an500); needs Debian's gcc-arm-none-eabi,
# libnewlib-arm-none-eabi and qemu-system-arm, which it installs itself as root with apt-get (CI).
# tests/test_pil.py runs on the images when they are built and is skipped, saying why, when not.
pil: $(STAMP)
	$(PY) -m tools.pil_build

# `make test` builds the image when the tools are there, and says why not (its tests then skip) when they are not
$(PIL_ELF): $(PIL_SRC) $(STAMP)
	$(PY) -m tools.pil_build --optional

# the documentation's figures (docs/FIGURES.md), each from the fps command named beside it
figures: $(STAMP)
	$(PY) -m ground.figures

fuzz: $(STAMP)
	$(PY) -m tests.fuzz_frames 1000000

mpy: $(STAMP)
	$(PY) -m tools.mpy_build

protocol-doc: $(STAMP)
	$(VENV)/bin/fps protocol table > protocol/PROTOCOL.md

# every restated constant from its one source: protocol/consts.py from the packet table, then the blocks the
# firmware's viper modules restate (tools/gen_consts.py); tests/test_protocol_gen.py and test_gen_consts.py check
consts: $(STAMP)
	$(PY) -m protocol.gen
	$(PY) -m tools.gen_consts

distfile: $(STAMP)
	$(VENV)/bin/fps distfile generate --source bps --duration 600 --seed 1 --cache-dir $(OUT)/bps_cache \
	    -o $(OUT)/bps600.dist

calibrate: $(STAMP)
	$(VENV)/bin/fps calibrate -o $(OUT)/calibration.json

hil: $(STAMP)
	$(VENV)/bin/fps distfile generate --source bps --duration 600 --seed 1 --cache-dir $(OUT)/bps_cache \
	    -o $(OUT)/bps600.dist
	$(VENV)/bin/fps calibrate -o $(OUT)/calibration.json
	$(VENV)/bin/fps hil --distfile $(OUT)/bps600.dist --calibration $(OUT)/calibration.json \
	    --duration 600 --runtime micropython --link serial -o $(OUT)/hil
	@echo "fps is $(VENV)/bin/fps: '. $(VENV)/bin/activate' puts it on the PATH; 'fps --help' lists its commands"

system: $(STAMP) $(NATMOD)
	$(VENV)/bin/fps calibrate -o $(OUT)/calibration.json
	$(VENV)/bin/fps system --duration 600 --seed 1 --runtime micropython --calibration $(OUT)/calibration.json \
	    --cache-dir $(OUT)/bps_cache -o $(OUT)/system

clean:
	rm -rf $(OUT) build *.egg-info .pytest_cache .hypothesis
	find . -name __pycache__ -prune -exec rm -rf {} + ; find . -name '*.mpy' -delete

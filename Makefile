# The two commands a newcomer needs:  make demo   and   make test
# Both install missing Debian packages first, then configure and build.
BUILD ?= build
JOBS ?= 2
CMAKE_FLAGS ?=
# The sanitizer tree: clang-14 with AddressSanitizer + UndefinedBehaviorSanitizer and
# libFuzzer coverage, one build for both the sanitized unit tests and the fuzzers.
# -O1 -gline-tables-only: quick enough to build on 2 cores, stacks still name file:line.
SAN_BUILD ?= build-sanitize
SAN_CXX ?= clang++-14
# The unit tests run under the sanitizers (docs/testing.md says why the others are not):
# in-process, no Chromium / podman / python / redis.
SAN_TESTS = tally_stats_tests tally_engine_tests tally_expr_tests tally_sampling_tests tally_integrate_tests \
  tally_server_tests
SAN_LABELS = ^(stats|engine|expr|sampling|integrate|server)$$
# Tests of those labels left out under the sanitizers (ctest -E regex), with the reason:
# AcceptBacksOffWhenDescriptorsRunOut uses up every file descriptor on purpose, and the
# sanitizer runtime needs descriptors itself (UBSan's vptr check validates memory through
# a pipe, the symbolizer is a subprocess): under EMFILE it reports "invalid vptr" on every
# virtual call. It runs in the normal suite.
SAN_EXCLUDE ?= ^HttpServerFds\.AcceptBacksOffWhenDescriptorsRunOut$$
FUZZ_TARGETS = fuzz_expr fuzz_job_spec fuzz_http fuzz_checkpoint fuzz_sse fuzz_cluster_wire fuzz_scene_files
# Seconds per fuzz target in `make fuzz` and CI; run longer by hand (tests/fuzz/README.md).
FUZZ_SECONDS ?= 60
# Sanitizer options for the sanitized tests and the fuzzers; suppressions (third-party
# code only, each with its reason) in tests/sanitize/.
SAN_SUPP = $(CURDIR)/tests/sanitize
export ASAN_OPTIONS ?= detect_leaks=1:halt_on_error=1:abort_on_error=1:check_initialization_order=1:strict_init_order=1
export LSAN_OPTIONS ?= suppressions=$(SAN_SUPP)/lsan.supp:print_suppressions=0
export UBSAN_OPTIONS ?= halt_on_error=1:print_stacktrace=1:suppressions=$(SAN_SUPP)/ubsan.supp
export ASAN_SYMBOLIZER_PATH ?= $(wildcard /usr/lib/llvm-14/bin/llvm-symbolizer)

.PHONY: all deps configure build test test-fast ctest-fast sanitize sanitize-build sanitize-build-all sanitize-run fuzz \
  fuzz-build fuzz-run configure-sanitize deps-demo demo bench study clean format

all: build

deps:
	@scripts/install-deps.sh all

$(BUILD)/build.ninja:
	cmake -S . -B $(BUILD) -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo $(CMAKE_FLAGS)

configure: deps $(BUILD)/build.ninja

build: configure
	cmake --build $(BUILD) -j $(JOBS)

# What CI runs (.ci/run): the whole suite, then the unit tests under ASan + UBSan, then
# each fuzz target for FUZZ_SECONDS. Any failure fails the run. Each stage prints its
# wall time; the summary is printed again at the end (figures: docs/testing.md).
test:
	@mkdir -p $(BUILD) && : >$(BUILD)/stages.txt
	@STAGE_LOG=$(BUILD)/stages.txt scripts/stage.sh build $(MAKE) --no-print-directory build
	@STAGE_LOG=$(BUILD)/stages.txt scripts/stage.sh ctest $(MAKE) --no-print-directory ctest-fast
	@STAGE_LOG=$(BUILD)/stages.txt scripts/stage.sh sanitize-build $(MAKE) --no-print-directory sanitize-build-all
	@STAGE_LOG=$(BUILD)/stages.txt scripts/stage.sh sanitize-tests $(MAKE) --no-print-directory sanitize-run
	@STAGE_LOG=$(BUILD)/stages.txt scripts/stage.sh fuzz $(MAKE) --no-print-directory fuzz-run
	@echo "== make test: every stage passed"; cat $(BUILD)/stages.txt

# The normal suite only (a few minutes): what to run while developing.
test-fast: build
	@$(MAKE) --no-print-directory ctest-fast

ctest-fast:
	cd $(BUILD) && ctest --output-on-failure -j $(JOBS) --timeout 900

$(SAN_BUILD)/build.ninja:
	cmake -S . -B $(SAN_BUILD) -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_COMPILER=$(SAN_CXX) \
	  "-DCMAKE_CXX_FLAGS_RELWITHDEBINFO=-O1 -gline-tables-only" \
	  -DTALLY_SANITIZE=ON -DTALLY_FUZZ=ON -DTALLY_BUILD_BENCH=OFF $(CMAKE_FLAGS)

configure-sanitize: deps $(SAN_BUILD)/build.ninja

# The unit tests (labels SAN_LABELS) under ASan + UBSan + LeakSanitizer, any report fatal.
sanitize: sanitize-build
	@$(MAKE) --no-print-directory sanitize-run

sanitize-build: configure-sanitize
	cmake --build $(SAN_BUILD) -j $(JOBS) --target $(SAN_TESTS)

# CI builds both sets in one ninja run (keeps both cores busy).
sanitize-build-all: configure-sanitize
	cmake --build $(SAN_BUILD) -j $(JOBS) --target $(SAN_TESTS) $(FUZZ_TARGETS)

sanitize-run:
	cd $(SAN_BUILD) && ctest --output-on-failure -j $(JOBS) --timeout 900 -L '$(SAN_LABELS)' -E '$(SAN_EXCLUDE)'

# Each libFuzzer target for FUZZ_SECONDS from the seed corpus in tests/fuzz/corpus
# (new inputs go to $(SAN_BUILD)/fuzz/corpus, findings to $(SAN_BUILD)/fuzz/); a crash,
# sanitizer report, leak or timeout fails.
fuzz: fuzz-build
	@$(MAKE) --no-print-directory fuzz-run

fuzz-build: configure-sanitize
	cmake --build $(SAN_BUILD) -j $(JOBS) --target $(FUZZ_TARGETS)

fuzz-run:
	@scripts/fuzz.sh $(SAN_BUILD) $(FUZZ_SECONDS) $(FUZZ_TARGETS)

# The demo needs only the server and the CLI, and only their packages (install-deps.sh demo).
deps-demo:
	@scripts/install-deps.sh demo

demo: deps-demo $(BUILD)/build.ninja
	cmake --build $(BUILD) -j $(JOBS) --target tally-server tally
	@scripts/demo.sh $(BUILD)

bench: build
	@scripts/bench.sh $(BUILD) $(BENCH)

study: deps
	@scripts/study.sh

format:
	clang-format -i $$(git ls-files '*.hpp' '*.cpp')

clean:
	rm -rf $(BUILD) $(SAN_BUILD)

# The two commands a newcomer needs:  make demo   and   make test
# Both install missing Debian packages first, then configure and build.
BUILD ?= build
JOBS ?= 2
CMAKE_FLAGS ?=
# The sanitizer tree: clang-14 with AddressSanitizer + UndefinedBehaviorSanitizer and
# libFuzzer coverage, one build for both the sanitized unit tests and the fuzzers.
SAN_BUILD ?= build-sanitize
SAN_CXX ?= clang++-14
SAN_TESTS = tally_stats_tests tally_engine_tests tally_expr_tests tally_sampling_tests tally_integrate_tests \
  tally_server_tests
SAN_LABELS = ^(stats|engine|expr|sampling|integrate|server)$$
FUZZ_TARGETS = fuzz_expr fuzz_job_spec fuzz_http fuzz_checkpoint fuzz_sse
FUZZ_SECONDS ?= 25

.PHONY: all deps configure build test test-fast sanitize fuzz configure-sanitize demo bench study clean format

all: build

deps:
	@scripts/install-deps.sh all

$(BUILD)/build.ninja:
	cmake -S . -B $(BUILD) -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo $(CMAKE_FLAGS)

configure: deps $(BUILD)/build.ninja

build: configure
	cmake --build $(BUILD) -j $(JOBS)

# What CI runs (.ci/run): the whole suite. The sanitizer tree and the fuzzers below are
# separate targets: they have not yet completed a run on the 2-core CI machine (see
# tests/fuzz/README.md), so they are not part of CI until they have.
test: test-fast

test-fast: build
	cd $(BUILD) && ctest --output-on-failure -j $(JOBS) --timeout 900

$(SAN_BUILD)/build.ninja:
	cmake -S . -B $(SAN_BUILD) -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_COMPILER=$(SAN_CXX) \
	  "-DCMAKE_CXX_FLAGS_RELWITHDEBINFO=-O1 -g1" \
	  -DTALLY_SANITIZE=ON -DTALLY_FUZZ=ON -DTALLY_BUILD_BENCH=OFF $(CMAKE_FLAGS)

configure-sanitize: deps $(SAN_BUILD)/build.ninja

# Unit tests (no e2e, lighting or statistical suites) under ASan + UBSan.
sanitize: configure-sanitize
	cmake --build $(SAN_BUILD) -j $(JOBS) --target $(SAN_TESTS)
	cd $(SAN_BUILD) && ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
	  ctest --output-on-failure -j $(JOBS) --timeout 900 -L '$(SAN_LABELS)'

# Each libFuzzer target for FUZZ_SECONDS from the seed corpus in tests/fuzz/corpus
# (new inputs go to $(SAN_BUILD)/fuzz/corpus, crashes to $(SAN_BUILD)/fuzz/).
fuzz: configure-sanitize
	cmake --build $(SAN_BUILD) -j $(JOBS) --target $(FUZZ_TARGETS)
	@scripts/fuzz.sh $(SAN_BUILD) $(FUZZ_SECONDS) $(FUZZ_TARGETS)

# The demo needs only the server and the CLI.
demo: configure
	cmake --build $(BUILD) -j $(JOBS) --target tally-server tally
	@scripts/demo.sh $(BUILD)

bench: build
	@scripts/bench.sh $(BUILD)

study: deps
	@scripts/study.sh

format:
	clang-format -i $$(git ls-files '*.hpp' '*.cpp')

clean:
	rm -rf $(BUILD) $(SAN_BUILD)

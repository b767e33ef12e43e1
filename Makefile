# The two commands a newcomer needs:  make demo   and   make test
# Both install missing Debian packages first, then configure and build.
BUILD ?= build
JOBS ?= 2
CMAKE_FLAGS ?=

.PHONY: all deps configure build test demo bench study clean format

all: build

deps:
	@scripts/install-deps.sh all

$(BUILD)/build.ninja:
	cmake -S . -B $(BUILD) -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo $(CMAKE_FLAGS)

configure: deps $(BUILD)/build.ninja

build: configure
	cmake --build $(BUILD) -j $(JOBS)

test: build
	cd $(BUILD) && ctest --output-on-failure -j $(JOBS) --timeout 900

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
	rm -rf $(BUILD)

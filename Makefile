# oneshot-lab: the two entry points of the README.
.PHONY: setup build smoke test check bench

setup:
	bash scripts/setup.sh

build: setup
	cargo build --release

# The main job: set up, build, and run the small default experiment.
smoke: build
	./target/release/oneshot-lab run experiments/smoke.toml

# The test command CI runs.
test: setup
	cargo fmt --check
	cargo clippy --release --all-targets -- -D warnings
	cargo test --release --lib --bins -- --test-threads=1
	cargo test --release --doc
	# The integration tests: two processes side by side, one test at a time in each (the script says why).
	bash scripts/integration-tests.sh
	# The GPU proof's script, rehearsed on the CPU with tiny settings.
	bash bench/gpu.sh --dry

# oneshot-lab: the two entry points of the README.
.PHONY: setup build smoke test check bench

setup:
	bash scripts/setup.sh

build: setup
	cargo build --release

# The main job: set up, build, and run the small default experiment.
smoke: build
	./target/release/oneshot-lab expert-check --robot panda --per-task 2
	./target/release/oneshot-lab contact-sheet --out runs/contact_sheet.png

# The test command CI runs.
test: setup
	cargo fmt --check
	cargo clippy --release --all-targets -- -D warnings
	cargo test --release

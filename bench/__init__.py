"""The benchmarks, by subject (bench/README.md). Each script runs as a file from the checkout
(``.venv/bin/python bench/agent/cost.py``); this package only makes ``bench.common`` and one
script's functions importable by another."""

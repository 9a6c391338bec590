"""The benchmarks' own tests: their driver (bench/run.py, bench/against.py) and their failure reports."""

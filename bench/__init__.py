"""Benchmarks (not tests): throughput, latency, memory and accuracy tables.

Each benchmark prints a table and writes ``bench/results/<name>.json``. Run all with
``make bench`` or one with ``python -m bench plan``.
"""

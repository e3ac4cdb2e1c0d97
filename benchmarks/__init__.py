"""torchfill's benchmarks: one harness (cases, methods incl. peers, scores, timing, result rows,
tables) and the suites that use it; ``python -m benchmarks --help`` lists them.

See docs/benchmark.md for the real-gap benchmark (its shipped masks, the held-out split) and
docs/experiments.md for every suite.
"""

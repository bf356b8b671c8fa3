"""Simulation, synthetic cases, evaluation and demo tools: what tests, the demo and the benchmark
use to make inputs with a known answer and score the merger on them; the node never imports it.
"""

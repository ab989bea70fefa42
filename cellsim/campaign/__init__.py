"""Test campaigns: sampled scenario variants simulated and checked in worker processes."""

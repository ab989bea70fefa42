"""The live twin: the scenario's diagram paced to the wall clock, beside the real cell, over Zenoh."""

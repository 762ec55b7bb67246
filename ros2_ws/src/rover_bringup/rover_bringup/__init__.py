"""Graph launcher, bag player, output recorder, parameters and evaluation (the globloc command)."""

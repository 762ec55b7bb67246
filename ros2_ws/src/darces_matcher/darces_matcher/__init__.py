"""2D DARCES matching of Local onto Global ROI networks: library, node, evaluation CLI."""

"""Offline Global Network preparation from a georeferenced orthoimage, and the gn_server node."""

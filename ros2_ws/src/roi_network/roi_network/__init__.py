"""Shared data model: ROI records and networks, 2D rigid transforms, GeoJSON and PointCloud2 codecs."""

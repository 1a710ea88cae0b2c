"""Detection networks: YOLOv5s (v6/v7 layout) with an optional Global Attention Module."""

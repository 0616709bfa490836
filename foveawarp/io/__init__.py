"""Scene file readers: one module per format."""

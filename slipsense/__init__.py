"""slipsense: slip detection and prediction from vision-based tactile sensors."""
__version__ = "0.1.0"

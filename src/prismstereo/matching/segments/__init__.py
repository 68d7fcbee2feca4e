"""Segments and planes: mean-shift segmentation of the reference image and robust disparity planes per segment
(fit, merge, support test, rendering)."""

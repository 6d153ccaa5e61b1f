"""The traced pipeline: pure JAX, jittable, no OpenCV and no files (host code lives in
``jaxvo.host``). Read in the order of the per-frame step, ``pipeline``."""

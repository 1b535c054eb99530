"""Navigation: Earth, time and ephemeris models, strapdown INS, error-state filter, smoother.

Pure computation: arrays in, arrays out; no file or network I/O.
"""

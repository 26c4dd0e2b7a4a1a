"""Pure Warp code: ``@wp.func`` helpers (one per primitive or sampling routine) and the integrator kernel factory.

No I/O here: the Python side (``pathtracer``) builds the arrays and launches.
"""

"""gaitrig engine: pure computation over arrays (numpy, scipy, open3d, opencv).

No web, no database, no global state. Files are read or written only by explicit
``load_*``/``save_*``/``read_*``/``write_*`` functions. Time is the first axis of every
series. Units are SI (m, s, rad); the world frame is right-handed, Z up, origin at
marker 1. Transforms are 4×4 and named ``T_<to>_<from>``; quaternions are w-first.
"""

__version__ = "0.1.0"

"""The simulated cell: a wall-mounted UR5 in MuJoCo rendering RGB-D views of a QR board.

Importing this package chooses the headless OpenGL backend (EGL, else
OSMesa) before MuJoCo is imported; see sim/gl_backend.py.
"""

from hec.sim.gl_backend import select_gl_backend

select_gl_backend()

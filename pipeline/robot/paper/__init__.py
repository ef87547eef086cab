"""The second paper's own chain: its stages one function each (chain: calibrate, chebyshev,
map-joints), the joint mapping (Eqs. 22-24), the grating closed loop (Eq. 26) and the evaluation of
Table 2 and ISO 9283 vAP."""

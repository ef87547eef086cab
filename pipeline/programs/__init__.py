"""Robot programs in, filtered programs out (contract section 11, ``jointcal correct --program``).

Reads KUKA KRL (``.src`` + ``.dat``), ABB RAPID (``.mod`` ...), FANUC TP ASCII (``.ls``) and URScript
(``.script``) programs, plays them through the nominal controller (inverse kinematics on the branch
each target's configuration data name) and rewrites their motion targets so that the real robot,
as the fitted model describes it, lands where the program meant. A layer above ``correct`` (it
calls its Newton correction) and below the command line.
"""

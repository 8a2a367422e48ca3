"""``hil-bench fit``: estimate a robot's physical parameters from its recordings.

``cases`` reads the recordings and replays one of them against an emulator of given
parameters, as the residuals a fit minimises (each fitted channel's error over its
tolerance); ``solve`` runs :func:`scipy.optimize.least_squares` over them, the replays of
one Jacobian in parallel processes, and works out each parameter's uncertainty; ``command``
is the sub-command.  The parameters are :data:`hil_emulator.profile.PARAMETERS`.
"""

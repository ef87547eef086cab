"""Units and reference values shared by both domains, named once (contract: angles in degrees,
angle errors in arcseconds, lengths in millimetres)."""

#: degC: the reference temperature of the models (the encoder's ``temperature`` effect, the robot's
#: ``thermal`` effect, whose lengths are nominal at it), of a campaign without temperatures and of
#: the simulated labs
REFERENCE_TEMPERATURE_C = 20.0
#: arcsec per deg: angles are degrees in files, angle errors arcseconds
ARCSEC_PER_DEG = 3600.0

"""
Names of the DYNAMIXEL models this package refuses, by model number.

Our own list of the models ROBOTIS's SDK knows (its dynamixel.model) and of the Protocol 1.0
models the e-manual documents, so a refusal can say what the servo on the bus is.  A model
leaves this list when the catalogue supports it.  Nothing is read at run time.
"""

# model number -> (name, what it is)
OTHER_MODELS: dict[int, tuple[str, str]] = {
    # The L42-10-S300-R on the original PRO firmware: its e-manual page contradicts itself
    # (models.pro_legacy says how) and dynamixel-workbench's table differs from it.
    35072: ('L42-10-S300-R', 'a DYNAMIXEL PRO whose published control table contradicts '
                             'itself'),
}

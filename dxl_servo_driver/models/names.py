"""
Names of the DYNAMIXEL models this package refuses, by model number.

Our own list of the models ROBOTIS's SDK knows (its dynamixel.model) and of the Protocol 1.0
models the e-manual documents, so a refusal can say what the servo on the bus is.  A model
leaves this list when the catalogue supports it.  Nothing is read at run time.
"""

# model number -> (name, what it is)
OTHER_MODELS: dict[int, tuple[str, str]] = {
    # Known only by dynamixel_hardware_interface (its dynamixel.model: 1700, xc335_t332.model):
    # no e-manual page, no datasheet, no gear ratio; the file gives no initial values nor a
    # current unit, lists Startup Configuration as 2 bytes (1 elsewhere) and places Indirect
    # Data 1..28 two bytes apart while its own Indirect Data Read alias (230 for entry 7) puts
    # them one apart.
    1700: ('XC335-T332', 'an X330-type servo with no published control table nor datasheet'),
}

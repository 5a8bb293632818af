"""
Names of the DYNAMIXEL models this package refuses, by model number.

Our own list of the models ROBOTIS's SDK knows (its dynamixel.model) and of the Protocol 1.0
models the e-manual documents, so a refusal can say what the servo on the bus is.  A model
leaves this list when the catalogue supports it.  Nothing is read at run time.
"""

# model number -> (name, what it is)
OTHER_MODELS: dict[int, tuple[str, str]] = {
    # Protocol 1.0 models (ROBOTIS e-manual model numbers).
    10: ('RX-10', 'a Protocol 1.0 DYNAMIXEL servo'),
    12: ('AX-12A', 'a Protocol 1.0 DYNAMIXEL servo'),
    18: ('AX-18A', 'a Protocol 1.0 DYNAMIXEL servo'),
    24: ('RX-24F', 'a Protocol 1.0 DYNAMIXEL servo'),
    28: ('RX-28', 'a Protocol 1.0 DYNAMIXEL servo'),
    29: ('MX-28', 'an MX servo on Protocol 1.0 firmware'),
    64: ('RX-64', 'a Protocol 1.0 DYNAMIXEL servo'),
    107: ('EX-106+', 'a Protocol 1.0 DYNAMIXEL servo'),
    300: ('AX-12W', 'a Protocol 1.0 DYNAMIXEL servo'),
    310: ('MX-64', 'an MX servo on Protocol 1.0 firmware'),
    320: ('MX-106', 'an MX servo on Protocol 1.0 firmware'),
    360: ('MX-12W', 'an MX servo on Protocol 1.0 firmware'),
    350: ('XL-320', 'an X-series servo with a control table unlike the others'),
    # The P series is the renamed PRO+; 2000 is the P-series successor of the PRO
    # H42-20-S300-R(A) (model 51201), which is named too so either search finds it.
    2000: ('PH42-020-S300-R',
           'a DYNAMIXEL-P servo (formerly PRO+ H42P-020-S300-R, successor of the PRO '
           'H42-20-S300-R)'),
    2010: ('PH54-100-S500-R', 'a DYNAMIXEL-P servo (formerly PRO+)'),
    2020: ('PH54-200-S500-R', 'a DYNAMIXEL-P servo (formerly PRO+)'),
    2100: ('PM42-010-S260-R', 'a DYNAMIXEL-P servo (formerly PRO+)'),
    2110: ('PM54-040-S250-R', 'a DYNAMIXEL-P servo (formerly PRO+)'),
    2120: ('PM54-060-S250-R', 'a DYNAMIXEL-P servo (formerly PRO+)'),
    4000: ('YM070-210-M001', 'a DYNAMIXEL-Y servo'),
    4010: ('YM070-210-B001', 'a DYNAMIXEL-Y servo'),
    4020: ('YM070-210-R051', 'a DYNAMIXEL-Y servo'),
    4030: ('YM070-210-R099', 'a DYNAMIXEL-Y servo'),
    4040: ('YM070-210-A051', 'a DYNAMIXEL-Y servo'),
    4050: ('YM070-210-A099', 'a DYNAMIXEL-Y servo'),
    4120: ('YM080-230-M001', 'a DYNAMIXEL-Y servo'),
    4130: ('YM080-230-B001', 'a DYNAMIXEL-Y servo'),
    4140: ('YM080-230-R051', 'a DYNAMIXEL-Y servo'),
    4150: ('YM080-230-R099', 'a DYNAMIXEL-Y servo'),
    4160: ('YM080-230-A051', 'a DYNAMIXEL-Y servo'),
    4170: ('YM080-230-A099', 'a DYNAMIXEL-Y servo'),
    35074: ('RH-P12-RN', 'a ROBOTIS gripper'),
    43289: ('M42-10-S260-R(A)', 'a DYNAMIXEL PRO (A) servo'),
    46097: ('M54-40-S250-R(A)', 'a DYNAMIXEL PRO (A) servo'),
    46353: ('M54-60-S250-R(A)', 'a DYNAMIXEL PRO (A) servo'),
    51201: ('H42-20-S300-R(A)', 'a DYNAMIXEL PRO (A) servo'),
    53769: ('H54-100-S500-R(A)', 'a DYNAMIXEL PRO (A) servo'),
    54025: ('H54-200-S500-R(A)', 'a DYNAMIXEL PRO (A) servo'),
}

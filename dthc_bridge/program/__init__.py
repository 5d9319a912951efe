"""Programs as users write them: the G-code dialects a person types or a CAM tool saves (here
LinuxCNC/QtPlasmaC NGC with parameters, expressions and o-word control flow), turned into the
plain lines the sender passes on, each still traceable to the source line it came from.
"""

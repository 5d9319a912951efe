(FireControl-style touch-off: probe down, lift off the float switch with G38.4, set Z where it opens)
G21 G90
G0 Z10
G0 X30 Y30
G38.2 Z-40 F300
G38.4 Z0.5 F20
G92 Z-1.4 (where the switch opens, the float is still pressed in by its travel less hysteresis)
G0 Z3.8
M3
G4 P0.4
G1 Z1.5 F600
G1 X130 Y30 F2800
G1 X130 Y80
M5
G0 Z10
M30

; grbl-style relay program: the program probes and does the start sequence itself
G21 G90
G0 Z10
G0 X30 Y30
G38.2 Z-40 F300
G92 Z-1.5 (the float switch trips 1.5 mm after contact)
G0 Z3.8
M03 S1000
G4 P0.4
G1 Z1.5 F600
H1
G1 X130 Y30 F2800
G1 X130 Y90
G1 X30 Y90
G1 X30 Y30
H0
M05
G0 Z10
M30

(FireControl-style relay program: vendor torch and THC codes, a Mach3 probe, inches)
G20 G90
G0 Z1.0
G0 X2.0 Y2.0
G31 Z-2.0 F12
G10 L20 P1 Z-0.06 (the float switch trips 0.06" after contact)
G0 Z0.15
M10 (torch on, this shop's post)
G4 P0.5
G1 Z0.06 F30
H1
G1 X6.0 Y2.0 F110
G1 X6.0 Y5.0
G1 X2.0 Y5.0
G1 X2.0 Y2.0
H0
M11 (torch off)
G0 Z1.0
M30

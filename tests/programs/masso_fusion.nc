(MASSO Fusion 360 post: no T112 M6, no G200: the daemon starts in plasma mode)
G90 G94 G17 # absolute
G21 # metric
G0 X10 Y10
M3
G4 P500 # pierce delay, ms in MASSO
M667 F500
G1 X110 Y10 F2600
G1 X110 Y60
G1 X10 Y60
G1 X10 Y10
M666
M5
M30

(MASSO program: the second cut stops after its pierce, for a cleaned surface)
G21 G90 # metric, absolute: a MASSO post option puts comments after #
T112 M6
G200 F250 P3.8 D300 C1.5 V0 A90 O1 S0
G0 Z20
G0 X50 Y50
M3
M667 F600
G1 X200 Y50 F3000
G1 X200 Y120
M666
M5
G0 Z20
G200 F250 P3.8 D300 C1.5 V0 A90 O1 S1 # stop after pierce for this one
G0 X80 Y80
M3
M667 F600
G1 X160 Y80 F3000
M666
M5
G0 Z20
M30

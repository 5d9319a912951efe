(SheetCAM MASSO post, a bracket on 6 mm plate, auto voltage)
(Material: mild steel 6 mm 65 A, cut height 1.5, pierce 3.8, delay 0.5 s)
G90 G94 G17
G21
T112 M6
G200 F300 P3.8 D500 C1.5 V0 A90 O1
M667 F3000
(outer profile)
G0 X40 Y40
M3
G1 X240 Y40 F2550
G1 X240 Y140
G2 X200 Y180 I-40 J0
G1 X40 Y180
G1 X40 Y40
M5
(a hole)
G0 X100 Y110
M3
G3 X100 Y110 I15 J0 F1300
M5
M30

(A shop's SheetCam post switching the torch with its own codes: map M13=M3 M15=M5)
G21 G90
G0 X20 Y20
M13
G1 X120 Y20 F2600
G1 X120 Y70
M15
G0 X0 Y0
M30

(no feed)
G21 G90
G0 X5
G1 X10 Y3

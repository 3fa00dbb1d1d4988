G1 X10 F100 (open

G1 X1 F100
M2

(end)

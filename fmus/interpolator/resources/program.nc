(Interpolator default program: a tour of the G-code subset in a 60 x 40 mm field)
(mm, absolute, XY plane, work offset G54; spindle 6000 rpm clockwise)
G21 G90 G17 G54
S6000 M3
G0 X0 Y0 Z2                   (rapid to the start, from wherever the tool is)
G1 Z0 F1200                   (plunge)
(a rational quadratic NURBS: the quarter circle of radius 10 mm around X0 Y10)
G6.2 P3 K0 X0 Y0 Z0 R1 F6000
K0 X10 Y0 R0.7071067811865476
K0 X10 Y10 R1
K1
K1
K1
G3 X0 Y20 I-10 J0            (continues on the same circle: tangent, same curvature)
G1 X-20 F3000                 (a line tangent to the arc: curvature jump)
G2 X-30 Y10 R10               (R form, clockwise)
G1 Y0                         (tangent line)
G1 X-10 Z-2 F1500             (corner, 3D line)
G6.2 P4 K0 X-10 Y0 Z-2 F4800  (a cubic NURBS arch, after a corner)
K0 X-5 Y4
K0 X5 Y4
K0 X10 Y0
K1
K1
K1
K1
G91 G1 Z2 F1000               (incremental)
G90 G0 X0 Y0 Z5               (rapid)
M5
M30

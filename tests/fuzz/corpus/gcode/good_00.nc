%
(header)
N10 g21 g90 ; mm
n20 g01 x1.5 y-.5 F600 (move)
N30 G00 Z+2
%

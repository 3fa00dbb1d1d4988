(A full slot entering the 100 x 60 x 30 mm block of the Workpiece defaults: 25 mm end mill, 3 mm deep,)
(900 mm/min along +X, 6000 rpm; the tool starts 1.5 mm before the block at X-14 Y30 Z27, see)
(scenarios/slot_entry_forcenet.toml)
G21 G90 G17 G54
S6000 M3
G1 X30 F900

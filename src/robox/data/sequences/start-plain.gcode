; The start of a job translated by robox-cli roboxise, for a head without a valve.
M150            ; nozzle targets from the reel(s)
M154            ; bed targets from the reel
M104            ; nozzle heater on, at the reel's temperature
M140            ; bed on, at the reel's temperature
G90
G28 X Y
G0 X20 Y75
G28 Z
G0 X200 Y75
G28 Z
G38             ; level the gantry
G0 X113 Y75
G28 Z
M190
M109
T0
G0 X10 Y10 Z0.3
G1 X60 E15 F1200 ; purge
G1 E-2 F1200
G0 Z1

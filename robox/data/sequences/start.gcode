; The start of a job translated by robox-cli roboxise, for a head with a valve.
; Heat from the reel, home, level the gantry, wait, select the nozzle, purge.
M150            ; nozzle targets from the reel(s)
M154            ; bed targets from the reel
M104            ; nozzle heater(s) on, at the reel's temperature
M140            ; bed on, at the reel's temperature
G90
G28 X Y
G0 X20 Y75
G28 Z           ; Z at the left leadscrew
G0 X200 Y75
G28 Z           ; and at the right
G38             ; level the gantry from the two
G0 X113 Y75
G28 Z
M190            ; wait for the bed
M109            ; and for the nozzle
T{nozzle}       ; select the nozzle: its valve is found and homed
G0 X10 Y10 Z0.3
G0 B1
G1 X60 E15 F1200 ; purge a line along the front edge
G0 B0
G0 Z1

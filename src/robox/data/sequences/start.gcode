; The start of a job translated by robox-cli roboxise, for a head with a valve.
; Heat from the reel, home, level the gantry, wait; then each nozzle the job uses is
; selected, its feed pressurised against the shut needle (G36 feeds until the drive
; slips) and a line purged along the front edge.
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
{purge}
G0 Z1

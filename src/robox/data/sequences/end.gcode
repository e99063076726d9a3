; The end of a job translated by robox-cli roboxise.
G0 B0           ; valve closed
{depressurise}
G91
G0 Z5           ; lift off the part
G90
G0 X10 Y140     ; park at the back
M104 S0         ; nozzle heater(s) off
M104 T0
M140 S0         ; bed off
M107            ; fan off
G37 S           ; unlock the door (without waiting for the bed to cool)
M84             ; motors off

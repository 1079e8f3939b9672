"""map_server's thresholds for reading a [0, 1] value as occupied / free (SPEC 2.2: 0.65 /
0.196), defined once for the map core, the map files and the plots. No imports: any layer may
use it."""

OCCUPIED_THRESH = 0.65  # a value (or cell probability) above this is occupied
FREE_THRESH = 0.196  # below this is free; between the two, unknown (trinary maps)
OCCUPIED_MIN = round(OCCUPIED_THRESH * 100)  # the same as a 0..100 cell value: >= 65 is occupied

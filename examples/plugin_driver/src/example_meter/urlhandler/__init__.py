"""pyserial URL handlers of the example plugin (``protocol_<scheme>`` modules); scatterlab
adds this package to pyserial's handler packages when a profile's URL uses ``simem1://``
(the scheme the plugin's registration names)."""

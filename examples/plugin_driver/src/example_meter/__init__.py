"""An example scatterlab driver plugin: the EM-1 power meter (a made-up instrument with a
small ASCII protocol, :mod:`example_meter.protocol`), its driver
(:class:`example_meter.driver.Em1PowerMeter`), its firmware emulator
(:mod:`example_meter.emulator`) behind the pyserial URL ``simem1://NAME`` and its
registration (:data:`example_meter.plugin.DRIVER`)."""

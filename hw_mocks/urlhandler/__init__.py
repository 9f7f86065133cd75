"""pyserial URL handlers for the emulated devices.

``serial.serial_for_url`` imports ``protocol_<scheme>`` from each package listed in
``serial.protocol_handler_packages``; this package is added there by
``drivers.transport.add_url_handler_package("hw_mocks.urlhandler")`` (the bench loader and
the test suite do it). Scheme names contain no ``-``: the module name must be importable.
"""

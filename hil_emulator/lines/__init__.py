"""Lines: the RS-485 bus (``rs485_bus``) and what a UART misreads (``uart_sampling``)."""

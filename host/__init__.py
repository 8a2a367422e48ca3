"""Host driver library: transports, hand and arm clients."""

#!/usr/bin/python3
"""A Modbus RTU server (pymodbus 3.0) with one slow register, for the driver's
late-reply tests.

usage: slow_rtu_peer.py DEVICE DELAYED_ADDRESS DELAY_S UNIT=ADDRESS:VALUE...

Serves holding registers (zero-based addresses) of the given units on the
serial DEVICE at 19200 8N1. A read that covers DELAYED_ADDRESS is answered
DELAY_S wall seconds late; the server answers requests one at a time, so
requests sent meanwhile wait in the line and their replies follow the late
one, as on a real RS-485 bus with a slow controller. Prints "ready" once the
port is open.
"""
import asyncio
import logging
import sys
import time

from pymodbus.datastore import (ModbusSequentialDataBlock, ModbusServerContext,
                                ModbusSlaveContext)
from pymodbus.server.async_io import ModbusSerialServer
from pymodbus.transaction import ModbusRtuFramer


class SlowBlock(ModbusSequentialDataBlock):
    def __init__(self, values, delayed_address, delay_s):
        super().__init__(0, values)
        self.delayed_address = delayed_address
        self.delay_s = delay_s

    def getValues(self, address, count=1):
        if address <= self.delayed_address < address + count:
            time.sleep(self.delay_s)  # blocks the server: later requests queue up
        return super().getValues(address, count)


async def main():
    device, delayed_address, delay_s = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
    registers = {}
    for spec in sys.argv[4:]:
        unit, rest = spec.split("=")
        address, value = rest.split(":")
        registers.setdefault(int(unit), {})[int(address)] = int(value)
    slaves = {}
    for unit, regs in registers.items():
        values = [0] * 4096
        for address, value in regs.items():
            values[address] = value
        block = SlowBlock(values, delayed_address, delay_s)
        slaves[unit] = ModbusSlaveContext(hr=block, ir=block, zero_mode=True)
    context = ModbusServerContext(slaves=slaves, single=False)
    server = ModbusSerialServer(context, ModbusRtuFramer, port=device, baudrate=19200,
                                bytesize=8, parity="N", stopbits=1,
                                ignore_missing_slaves=True)
    await server.start()
    print("ready", flush=True)
    while True:
        await asyncio.sleep(3600)


if __name__ == "__main__":
    logging.basicConfig(level=logging.ERROR)
    asyncio.run(main())

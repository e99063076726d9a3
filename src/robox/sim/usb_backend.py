"""A pyusb backend that presents a virtual printer as the real Robox USB device.

`usb.core.find(idVendor=0x16D0, idProduct=0x081B, backend=VirtualRoboxBackend(printer))`
returns a device with the printer's descriptors: a CDC-ACM device whose
communication interface 0 has an interrupt IN endpoint (0x83) and whose data
interface 1 has bulk OUT 0x02 and bulk IN 0x81, 64-byte packets. Host code
written for the hardware (detach the kernel driver, claim, bulk transfers)
runs unchanged. A bulk read runs the firmware until a reply is there, or
until the read's timeout has passed in simulated time.
"""

from __future__ import annotations

import errno

import usb.backend
import usb.core

from robox.hardware.usb import ReplyWaiting
from robox.sim.printer import VirtualPrinter

VENDOR_ID = 0x16D0
PRODUCT_ID = 0x081B
EP_NOTIFY, EP_OUT, EP_IN = 0x83, 0x02, 0x81
PACKET = 64
STRINGS = {1: "CEL", 2: "Robox"}
LANGID_EN_US = 0x0409
SPEED_FULL = 2  # usb.util.SPEED_FULL


class _Descriptor:
    def __init__(self, **fields):
        self.__dict__.update(fields)


class _DeviceId:
    """The backend's handle for the one device it has."""


class VirtualRoboxBackend(usb.backend.IBackend):
    virtual = True  # its printer is locked by its state directory, not as a USB port

    def __init__(self, printer: VirtualPrinter):
        self.printer = printer
        self.device = _DeviceId()
        self.claimed: set[int] = set()
        self.configuration = 0
        self.line_state = 0
        self.kernel_driver = {0: True, 1: True}  # cdc_acm binds it, as on Linux

    # ------------------------------------------------------------ enumerate
    def enumerate_devices(self):
        if self.printer.usb.connected:
            yield self.device

    def get_device_descriptor(self, dev):
        return _Descriptor(
            bLength=18, bDescriptorType=1, bcdUSB=0x0200, bDeviceClass=0x02,
            bDeviceSubClass=0, bDeviceProtocol=0, bMaxPacketSize0=PACKET,
            idVendor=VENDOR_ID, idProduct=PRODUCT_ID, bcdDevice=0x0100, iManufacturer=1,
            iProduct=2, iSerialNumber=3, bNumConfigurations=1, address=7, bus=1,
            port_number=1, port_numbers=(1,), speed=SPEED_FULL)

    def get_configuration_descriptor(self, dev, config):
        if config != 0:
            raise IndexError("no such configuration")
        return _Descriptor(bLength=9, bDescriptorType=2, wTotalLength=67, bNumInterfaces=2,
                           bConfigurationValue=1, iConfiguration=0, bmAttributes=0x80,
                           bMaxPower=50, extra_descriptors=[])

    def get_interface_descriptor(self, dev, intf, alt, config):
        if alt != 0 or intf not in (0, 1) or config != 0:
            raise IndexError("no such interface")
        if intf == 0:
            return _Descriptor(bLength=9, bDescriptorType=4, bInterfaceNumber=0,
                               bAlternateSetting=0, bNumEndpoints=1, bInterfaceClass=0x02,
                               bInterfaceSubClass=0x02, bInterfaceProtocol=0x01,
                               iInterface=0, extra_descriptors=[])
        return _Descriptor(bLength=9, bDescriptorType=4, bInterfaceNumber=1,
                           bAlternateSetting=0, bNumEndpoints=2, bInterfaceClass=0x0A,
                           bInterfaceSubClass=0, bInterfaceProtocol=0, iInterface=0,
                           extra_descriptors=[])

    def get_endpoint_descriptor(self, dev, ep, intf, alt, config):
        if alt != 0 or (intf, ep) not in ((0, 0), (1, 0), (1, 1)):
            raise IndexError("no such endpoint")
        if intf == 0:
            address, attributes, size, interval = EP_NOTIFY, 0x03, 8, 16
        else:
            address, attributes, size, interval = ((EP_OUT, 0x02, PACKET, 0), (EP_IN, 0x02,
                                                                               PACKET, 0))[ep]
        return _Descriptor(bLength=7, bDescriptorType=5, bEndpointAddress=address,
                           bmAttributes=attributes, wMaxPacketSize=size, bInterval=interval,
                           bRefresh=0, bSynchAddress=0, extra_descriptors=[])

    # -------------------------------------------------------------- handles
    def _check_connected(self) -> None:
        if not self.printer.usb.connected:
            raise usb.core.USBError("No such device (it may have been disconnected)",
                                    -4, errno.ENODEV)

    def open_device(self, dev):
        self._check_connected()
        return self.device

    def close_device(self, dev_handle):
        self.claimed.clear()

    def set_configuration(self, dev_handle, config_value):
        self._check_connected()
        self.configuration = config_value

    def get_configuration(self, dev_handle):
        return self.configuration

    def set_interface_altsetting(self, dev_handle, intf, altsetting):
        pass

    def claim_interface(self, dev_handle, intf):
        self._check_connected()
        if self.kernel_driver.get(intf):
            raise usb.core.USBError("Resource busy (the kernel's cdc_acm driver holds it)",
                                    -6, errno.EBUSY)
        self.claimed.add(intf)

    def release_interface(self, dev_handle, intf):
        self.claimed.discard(intf)

    def is_kernel_driver_active(self, dev_handle, intf):
        return self.kernel_driver.get(intf, False)

    def detach_kernel_driver(self, dev_handle, intf):
        self.kernel_driver[intf] = False

    def attach_kernel_driver(self, dev_handle, intf):
        self.kernel_driver[intf] = True

    def reset_device(self, dev_handle):
        pass

    def clear_halt(self, dev_handle, ep):
        pass

    # ------------------------------------------------------------ transfers
    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data,
                      timeout):
        self._check_connected()
        if bmRequestType == 0x80 and bRequest == 6 and wValue >> 8 == 3:  # string descriptor
            index = wValue & 0xFF
            if index == 0:
                raw = bytes([4, 3]) + LANGID_EN_US.to_bytes(2, "little")
            else:
                text = STRINGS.get(index) or self._serial()
                encoded = text.encode("utf-16-le")
                raw = bytes([2 + len(encoded), 3]) + encoded
            count = min(len(raw), len(data))
            for i in range(count):
                data[i] = raw[i]
            return count
        if bmRequestType == 0x21 and bRequest == 0x22:  # SET_CONTROL_LINE_STATE
            self.line_state = wValue
            return 0
        if bmRequestType == 0x21 and bRequest == 0x20:  # SET_LINE_CODING
            return len(data)
        return len(data) if isinstance(data, (bytes, bytearray)) else 0

    def _serial(self) -> str:
        unique = self.printer.firmware.parameters.unique_id()
        return unique.split(b"\0", 1)[0].decode("ascii", "replace")[:32] or "0"

    def _claimed(self, intf: int) -> None:
        if intf not in self.claimed:
            raise usb.core.USBError("Interface not claimed", -3, errno.EACCES)

    def _bulk_link(self, intf: int):
        """The printer's USB link, for a bulk transfer on `intf` (the checks of
        _check_connected and _claimed, with one look at the link: every transfer
        makes them)."""
        usb_link = self.printer.usb
        if not usb_link.connected:
            self._check_connected()
        if intf not in self.claimed:
            self._claimed(intf)
        return usb_link

    def bulk_write(self, dev_handle, ep, intf, data, timeout):
        payload = bytes(data)
        self._bulk_link(intf).host_write(payload)
        return len(payload)

    def bulk_read(self, dev_handle, ep, intf, buff, timeout):
        usb_link = self._bulk_link(intf)
        if not usb_link.reply_waiting:
            seconds = (timeout or 1000) / 1000.0
            # a USB host sees a reply as soon as it is sent, even mid-line
            self.printer.run_until(ReplyWaiting(usb_link, or_gone=True), seconds)
            self._check_connected()
        if not usb_link.reply_waiting:
            raise usb.core.USBTimeoutError("Operation timed out", -7, errno.ETIMEDOUT)
        chunk = usb_link.host_read(len(buff))
        memoryview(buff)[: len(chunk)] = chunk
        return len(chunk)

    def intr_read(self, dev_handle, ep, intf, buff, timeout):
        raise usb.core.USBTimeoutError("Operation timed out", -7, errno.ETIMEDOUT)


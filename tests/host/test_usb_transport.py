"""The USB transport's bulk transfers: the backend's own calls on the open handle, as
pyusb's Device.write and Device.read make them, with the endpoints' methods where this
pyusb keeps its backend elsewhere. Both give the printer the same bytes and the host the
same replies."""

from array import array

import pytest
import usb.core

from robox.formats.protocol import reply_length
from robox.host.client import Printer
from robox.host.transport import (
    DATA_INTERFACE,
    Disconnected,
    NoReply,
    UsbTransport,
    _bulk_calls,
)
from robox.sim.printer import VirtualPrinter
from robox.sim.usb_backend import EP_IN, EP_OUT, VirtualRoboxBackend


class LibusbShaped(VirtualRoboxBackend):
    """The virtual backend, checking each bulk transfer's arguments as pyusb's libusb1
    backend uses them (buffer_info() of a byte array, the claimed interface, the bulk
    endpoints' addresses) and recording them."""

    def __init__(self, printer):
        super().__init__(printer)
        self.transfers: list[tuple[str, int, bytes]] = []

    def bulk_write(self, dev_handle, ep, intf, data, timeout):
        assert isinstance(data, array) and data.typecode == "B"
        data.buffer_info()
        assert (dev_handle, ep, intf) == (self.device, EP_OUT, DATA_INTERFACE)
        self.transfers.append(("out", timeout, data.tobytes()))
        return super().bulk_write(dev_handle, ep, intf, data, timeout)

    def bulk_read(self, dev_handle, ep, intf, buff, timeout):
        assert isinstance(buff, array) and buff.typecode == "B"
        assert len(buff) % 64 == 0
        assert (dev_handle, ep, intf) == (self.device, EP_IN, DATA_INTERFACE)
        count = super().bulk_read(dev_handle, ep, intf, buff, timeout)
        self.transfers.append(("in", timeout, buff[:count].tobytes()))
        return count


def session(direct: bool):
    """A few commands through a transport on a fresh printer: the transport, its
    backend's record, and the replies the host read."""
    virtual = VirtualPrinter()
    virtual.settle()
    backend = LibusbShaped(virtual)
    device = usb.core.find(idVendor=0x16D0, idProduct=0x081B, backend=backend)
    transport = UsbTransport(device)
    if not direct:
        transport._direct = None
    printer = Printer(transport)
    transport.timeout_used = printer.timeout
    replies = [printer.transact(frame) for frame in
               (b"\xb0", b"\xb4", b"\x95" + b"0004M115", b"\xb3", b"\x96")]
    return transport, backend, replies


def test_the_backend_is_called_directly_with_what_libusb_takes():
    transport, backend, replies = session(direct=True)
    assert transport._direct is not None  # this pyusb keeps its backend where it is looked for
    # the status report (222 bytes) in one read of four whole packets, and its bytes
    out = [data for kind, _, data in backend.transfers if kind == "out"]
    assert out[1:] == [b"\xb0", b"\xb4", b"\x950004M115", b"\xb3", b"\x96"]
    reads = [data for kind, _, data in backend.transfers if kind == "in"]
    assert reads[1] == replies[0] and len(reads[1]) == reply_length(reads[1]) == 222
    assert {timeout for _, timeout, _ in backend.transfers} == {transport.timeout_used}


def test_direct_and_through_the_endpoints_give_the_same_bytes():
    _, direct_backend, direct_replies = session(direct=True)
    _, endpoint_backend, endpoint_replies = session(direct=False)
    assert direct_replies == endpoint_replies
    assert direct_backend.transfers == endpoint_backend.transfers
    assert [reply[0] for reply in direct_replies] == [0xE1, 0xE4, 0xE7, 0xE3, 0xE0]


def test_where_the_backend_and_handle_are_not_found_nothing_is_called_directly():
    class Parts:
        def __init__(self, **fields):
            self.__dict__.update(fields)

    def bulk(*args):
        raise AssertionError("not to be called")

    whole = Parts(_ctx=Parts(backend=Parts(bulk_write=bulk, bulk_read=bulk), handle=7))
    assert _bulk_calls(whole) == (bulk, bulk, 7)
    assert _bulk_calls(Parts()) is None  # a pyusb that names its parts otherwise
    assert _bulk_calls(Parts(_ctx=Parts(backend=whole._ctx.backend))) is None
    assert _bulk_calls(Parts(_ctx=Parts(backend=whole._ctx.backend, handle=None))) is None
    assert _bulk_calls(Parts(_ctx=Parts(backend=Parts(bulk_write=bulk), handle=7))) is None
    assert _bulk_calls(Parts(_ctx=Parts(backend=Parts(bulk_write=1, bulk_read=bulk),
                                        handle=7))) is None


def test_without_them_the_transfers_go_through_the_endpoints(monkeypatch):
    from robox.host import transport as transport_module

    virtual = VirtualPrinter()
    virtual.settle()
    backend = LibusbShaped(virtual)
    device = usb.core.find(idVendor=0x16D0, idProduct=0x081B, backend=backend)
    assert _bulk_calls(device) is None  # not open yet: nothing to call on
    monkeypatch.setattr(transport_module, "_bulk_calls", lambda device: None)
    transport = UsbTransport(device)
    assert transport._direct is None
    printer = Printer(transport)
    reply = printer.transact(b"\xb4")
    assert reply[:1] == b"\xe4"
    assert backend.transfers[-1] == ("in", printer.timeout, reply)


def test_errors_on_the_direct_path_are_the_transport_s_own():
    virtual = VirtualPrinter()
    virtual.settle()
    device = usb.core.find(idVendor=0x16D0, idProduct=0x081B,
                           backend=VirtualRoboxBackend(virtual))
    transport = UsbTransport(device)
    assert transport._direct is not None
    transport.write(b"\xb4", 100)
    assert transport.read(64, 100)[:1] == b"\xe4"
    with pytest.raises(NoReply):  # nothing more to read
        transport.read(64, 100)
    virtual.usb.disconnect()
    with pytest.raises(Disconnected):
        transport.write(b"\xb0")
    transport.close()
    assert transport._direct is None

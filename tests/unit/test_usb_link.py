"""The USB link's conditions a host waits on (src/robox/hardware/usb.py)."""

from robox.hardware.usb import ReplyWaiting, UsbLink


def test_a_reply_waits_once_the_device_sends_and_until_the_host_reads_it():
    link = UsbLink()
    reply, reply_or_gone = ReplyWaiting(link), ReplyWaiting(link, or_gone=True)
    assert not reply() and not reply_or_gone()
    link.device_send(b"\xe1" + bytes(8))
    assert reply() and reply_or_gone()
    assert link.host_read(64) == b"\xe1" + bytes(8)
    assert not reply() and not reply_or_gone()


def test_a_gone_link_ends_only_the_wait_that_asks_for_it():
    link = UsbLink()
    link.disconnect()
    assert not ReplyWaiting(link)()
    assert ReplyWaiting(link, or_gone=True)()
    link.device_send(b"\xe1")  # dropped while disconnected
    assert not ReplyWaiting(link)()
    link.connect()
    assert not ReplyWaiting(link, or_gone=True)()


def test_each_time_the_link_goes_down_is_counted_once():
    link = UsbLink()
    link.host_write(b"\x91abc")
    link.disconnect()
    link.disconnect()  # (already down: the same time)
    assert link.downs == 1 and not link.arriving
    link.connect()
    link.disconnect()
    assert link.downs == 2

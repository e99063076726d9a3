"""OctoPrint plugin for the CEL Robox (`pip install robox[octoprint]`).

Two ways OctoPrint reaches a Robox, both offered by this plugin:

- **The Robox ports** (`robox:usb`, `robox:sim`, `robox:sim:DIR`,
  `robox:serial:PATH`, in OctoPrint's port list): OctoPrint talks to
  `octoprint_robox.link.RoboxLink`, which drives the printer in Robox mode through
  robox's own client. Temperatures come under their names (tool0 = nozzle 0,
  tool1 = nozzle 1, bed, chamber = ambient), uploads to the printer's card print
  while they upload, jobs on the card are started, followed, paused, resumed and
  cancelled, and the printer's errors appear as OctoPrint notifications. A printer a
  text host left in the middle of a line is taken over (the line is ended).
- **The plain serial port** (/dev/ttyACM*, or a virtual printer's pty) in text
  (Pronterface) mode. A Robox stays in Robox mode, deaf to text, from the first
  frame a host sends it until it is reset; so when OctoPrint connects to a Robox's
  port, the plugin first hands the printer over to text
  (`robox.host.textmode.hand_to_text_host`): an idle printer is reset and OctoPrint
  opens the port once it answers text; a printer with a job on is not reset (that
  would end the job) and OctoPrint is connected to it through the Robox link
  instead, following the job. On the text port the plugin renames the Robox's M105
  fields (`S:` is nozzle 0, `T:` nozzle 1) and writes OctoPrint's tool temperatures
  in the Robox's words.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time

PREFIX = "robox:"
PLAIN_NAMES = {"S": "T0", "T0": "T1", "T": "T1", "A": "C"}


class RoboxPlugin:
    """The plugin's hooks (it needs no other part of OctoPrint's plugin API)."""

    def __init__(self):
        self._current = None  # the link of the robox: port OctoPrint is connected to
        self._plain_robox = None  # the connection whose M105 showed a Robox in text mode
        self._log = logging.getLogger("octoprint.plugins.robox")

    # ------------------------------------------------------------------ ports
    def port_names(self, candidates, *args, **kwargs):
        from robox.sim.served import list_served

        names = [f"{PREFIX}usb", f"{PREFIX}sim"]
        served = list_served()
        names += [f"{PREFIX}sim:{one['state']}" for one in served]
        names += [one["pty"] for one in served]  # a virtual printer's plain (text) port
        return [n for n in names if n not in candidates]

    def serial_factory(self, comm_instance, port, baudrate, read_timeout, *args, **kwargs):
        if not port or port == "AUTO":
            return None
        if not port.startswith(PREFIX):
            return self._plain_port(port, float(read_timeout))
        from octoprint_robox.link import RoboxLink
        from robox.host.devices import open_printer

        spec = port[len(PREFIX):]
        stack = contextlib.ExitStack()
        printer = stack.enter_context(open_printer(spec, take_over=True))
        link = RoboxLink(printer, float(read_timeout), closer=stack.close, port=port)
        self._current = link
        return link

    def _plain_port(self, port: str, read_timeout: float):
        """A Robox's own serial port, handed over to text before OctoPrint opens it
        (None: OctoPrint opens it itself), or, when a job keeps the printer in Robox
        mode, the Robox link to it."""
        from octoprint_robox.link import RoboxLink
        from robox.host.textmode import hand_to_text_host, is_robox_port

        self._current = None
        if not is_robox_port(port):
            return None  # another printer: nothing to do
        printer = hand_to_text_host(port)
        if printer is None:
            self._log.info("%s: the Robox answers text", port)
            return None
        link = RoboxLink(printer, read_timeout, closer=printer.transport.close, port=port)
        job = link.following  # the link asked the printer's status as it began
        self._log.info("%s: the Robox is busy in Robox mode (job %s): connected through "
                       "the Robox link", port, job)
        link.notify(f"{'job ' + job if job else 'a command'} is under way in Robox mode, "
                    "which only a reset leaves: OctoPrint follows it through the Robox "
                    "link. Reconnect once the printer is idle for the text port.")
        self._current = link
        return link

    # ------------------------------------------------------ plain serial names
    def temperatures(self, comm_instance, parsed, *args, **kwargs):
        """Pronterface mode's M105 (`S:` nozzle 0, `T:` nozzle 1, `B:` bed, `A:` ambient)
        under OctoPrint's names. OctoPrint has already read `T:` as the current tool."""
        if "S" not in parsed or "A" not in parsed:
            return parsed  # not a Robox's report
        self._plain_robox = comm_instance
        renamed = {}
        for key, value in parsed.items():
            if key.startswith("T") and key not in ("T", "T0", "T1"):
                continue
            renamed[PLAIN_NAMES.get(key, key)] = value
        return renamed

    def targets(self, comm_instance, phase, cmd, cmd_type, gcode, *args, **kwargs):
        """On a plain serial port to a Robox, OctoPrint's `M104 T1 S210` (tool 1) in the
        Robox's own words (`M104 T210`): see `robox_temperature_lines`."""
        if comm_instance is None or comm_instance is not self._plain_robox:
            return None
        from octoprint_robox.link import robox_temperature_lines

        return robox_temperature_lines(cmd)

    # ------------------------------------------------------------ card upload
    def card_upload(self, printer, filename, path, started, succeeded, failed,
                    *args, **kwargs):
        link = self._current
        if link is None or link.closed:
            return None  # not a Robox port: OctoPrint's own upload
        from pathlib import Path

        from octoprint_robox.link import shown
        from robox.formats.sdcard import default_id
        from robox.gcode import job_file
        from robox.gcode.files import inspect

        # the job is prepared first, so that its id follows send-job's rule (name and
        # the prepared content's SHA-1); it is uploaded in the background
        options = None
        detected = inspect(path)
        if detected.from_slicer:
            from robox.cli.printer import printer_options

            options = printer_options(link.printer, None, None, None)
        prepared = contextlib.ExitStack()
        job = prepared.enter_context(job_file(path, options, detected))
        try:
            job.refuse_long_lines()  # before the first chunk, as send-job does
        except BaseException:
            prepared.close()
            raise
        remote = default_id(Path(filename).stem, job.sha1)

        def run() -> None:
            begun = time.monotonic()
            told = []

            def ready() -> None:
                # OctoPrint selects (and, if asked, prints) the file once told it is
                # stored: told as soon as it can print, so it prints while uploading
                told.append(True)
                succeeded(filename, shown(remote), time.monotonic() - begun)

            started(filename, shown(remote))
            try:
                with prepared, open(job.path, "rb") as source:
                    link.upload(source, remote, job.lines, ready=ready, sha1=job.sha1)
            except Exception as exc:
                self._log.exception("upload of %s to the Robox failed", filename)
                if told:
                    link.notify(f"the upload of {shown(remote)} failed: {exc}")
                else:
                    failed(filename, shown(remote), time.monotonic() - begun)

        threading.Thread(target=run, name="robox-upload", daemon=True).start()
        return shown(remote)


__plugin_name__ = "Robox"
__plugin_pythoncompat__ = ">=3.11,<4"
__plugin_description__ = ("CEL Robox printers: the right temperatures, uploads that print "
                          "while they upload, jobs on the printer's card, its errors.")


def __plugin_load__():
    global __plugin_hooks__
    plugin = RoboxPlugin()
    __plugin_hooks__ = {
        "octoprint.comm.transport.serial.additional_port_names": plugin.port_names,
        "octoprint.comm.transport.serial.factory": plugin.serial_factory,
        "octoprint.comm.protocol.temperatures.received": plugin.temperatures,
        "octoprint.comm.protocol.gcode.queuing": plugin.targets,
        "octoprint.printer.sdcardupload": plugin.card_upload,
    }

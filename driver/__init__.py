"""fpscan scanner side: the serial protocol, the host driver, scan files and the
simulated Fabry-Perot scanner. Deployable alone; never imports `service`.

Modules (protocol: docs/protocol.md):

- `framing` — COBS frames with header and CRC-32; `commands` — SCPI command syntax;
  `aline` — the A-line frame payload; `plan` — plan JSON reading and the device plan image.
- `host` — the host driver (`Scanner`: identify, upload, commands; `ScanSession`: one
  scan with recovery); `transport` — its readers (relay process, pyserial reader thread,
  direct); `relay` — the process that drains a local tty; `acquire` — plan → scan file.
- `scanfile` — the HDF5 scan file; `physics` — exact forward models.
- `simulator` — the simulated FP scanner on a pty; `sources` — its A-line sources;
  `faults` — its seeded fault injection.

Keep this file free of heavy imports: `fpscan.physics` is imported by
`fpscan.service.recon` and must stay numpy/scipy/finufft only.
"""

__all__: list[str] = []  # the package's API is its modules

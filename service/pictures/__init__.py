"""fpscan's pictures: every PNG the library, the server and the command line draw (result MIPs
and depth slices, mask previews, live previews, sO2 maps) comes from :mod:`.render`, in the
frame of :mod:`.frame` (axes in mm at equal aspect, y down, ticks and colour bar drawn with
Pillow). Formats: docs/file-formats.md, "Renderings"."""

__all__: list[str] = []

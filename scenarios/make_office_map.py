"""Draws the shipped office map, ``scenarios/unicycle_office.pgm`` and ``scenarios/unicycle_office.yaml`` (ROS map_server's
format, as a SLAM package's map saver writes it), for the ``unicycle_office`` scenario.

    python scenarios/make_office_map.py      # writes both files beside this script

A 10 m x 6 m floor of 0.1 m cells: outer walls; a wall across the middle (y 2.8 to 3.2) with two
doors, a narrow one on the left (x 1.5 to 2.5, the short way from the offices below to the room
above) and a wide one on the right (x 7.5 to 9.0); below it, three office bays (short walls at x 3.4
to 3.6 and 6.4 to 6.6 from y 0 to 1.0) along a corridor; above, a room split by a partition (x 4.9 to
5.1, y 5.0 to 6.0). The image is drawn as map_server saves one: 0 occupied,
254 free, its first row the map's top.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

RES = 0.1  # m per cell
WIDTH, HEIGHT = 10.0, 6.0  # m
WALLS = (  # (x0, x1, y0, y1) in metres
    (0.0, 10.0, 0.0, 0.1), (0.0, 10.0, 5.9, 6.0), (0.0, 0.1, 0.0, 6.0), (9.9, 10.0, 0.0, 6.0),  # outer
    (0.0, 1.5, 2.8, 3.2), (2.5, 7.5, 2.8, 3.2), (9.0, 10.0, 2.8, 3.2),  # the middle wall and its doors
    (3.4, 3.6, 0.0, 1.0), (6.4, 6.6, 0.0, 1.0),  # the offices' short walls
    (4.9, 5.1, 5.0, 6.0),  # the partition of the room above
)


def occupancy() -> np.ndarray:
    """(rows, cols) bool, row 0 the bottom: True where a cell's centre lies in a wall."""
    cols, rows = int(round(WIDTH / RES)), int(round(HEIGHT / RES))
    x = (np.arange(cols) + 0.5) * RES
    y = (np.arange(rows) + 0.5) * RES
    grid = np.zeros((rows, cols), dtype=bool)
    for x0, x1, y0, y1 in WALLS:
        grid[np.ix_((y > y0) & (y < y1), (x > x0) & (x < x1))] = True
    return grid


def main(folder: Path = Path(__file__).resolve().parent) -> None:
    image = np.where(occupancy()[::-1], 0, 254).astype(np.uint8)  # the image's first row: the map's top
    Image.fromarray(image, mode="L").save(folder / "unicycle_office.pgm")
    (folder / "unicycle_office.yaml").write_text("image: unicycle_office.pgm\nresolution: 0.1\norigin: [0.0, 0.0, 0.0]\n"
                                        "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")


if __name__ == "__main__":
    main()

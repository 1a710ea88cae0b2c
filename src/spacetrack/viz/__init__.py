"""Drawing boxes and trails, contact sheets, and MP4 clips for looking at data and results."""

from spacetrack.viz.draw import draw_boxes, draw_trails, id_color
from spacetrack.viz.sheet import contact_sheet
from spacetrack.viz.video import VideoWriter, read_video_frames

__all__ = ["VideoWriter", "contact_sheet", "draw_boxes", "draw_trails", "id_color", "read_video_frames"]

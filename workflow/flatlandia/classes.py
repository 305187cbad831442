"""The 42 Flatlandia object classes (Mapillary Vistas labels); the class id is the index."""

CLASSES = [
    "driveway", "marking--discrete--arrow--left", "marking--discrete--arrow--right",
    "marking--discrete--arrow--split-left-or-straight", "marking--discrete--arrow--split-right-or-straight",
    "marking--discrete--arrow--straight", "crosswalk-plain", "crosswalk-zebra", "give-way-row",
    "give-way-single", "stop-line", "marking--discrete--symbol--bicycle", "marking--discrete--text",
    "other-marking", "banner", "object--sign--advertisement", "object--sign--information",
    "object--sign--store", "object--support--traffic-sign-frame", "object--traffic-sign",
    "object--traffic-sign--direction", "object--traffic-sign--information-parking", "object--trash-can",
    "object--bench", "object--street-light", "object--support--pole",
    "object--traffic-light--general-upright", "object--traffic-light--general-horizontal",
    "object--traffic-light--general-single", "object--traffic-light--general-other",
    "object--traffic-light--pedestrians", "object--traffic-light--cyclists", "object--manhole",
    "object--junction-box", "object--water-valve", "object--bike-rack", "object--catch-basin",
    "object--cctv-camera", "object--fire-hydrant", "object--mailbox", "object--parking-meter",
    "object--phone-booth",
]
N_CLASSES = len(CLASSES)

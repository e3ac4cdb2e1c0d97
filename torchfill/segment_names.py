"""The name tables of :mod:`torchfill.segments`: the segments of the common marker sets.

Marker names are normalised (lower case, no separators); "#" stands for the side letter (l / r)
and makes a left and a right segment. A marker may appear in several segments.
"""
from __future__ import annotations

_SIDED = {
    # Vicon Plug-in Gait / full body, HDM05, CMU (the same set with LFWT..RBWT waist markers)
    "upper_arm": ["#sho", "#upa", "#elb"],
    "forearm": ["#elb", "#frm", "#fra", "#wra", "#wrb"],
    "hand": ["#wra", "#wrb", "#fin"],
    "thigh": ["#thi", "#thi2", "#kne", "#thap", "#thad", "#kax", "#kd1", "#kd2",
              # CAST-style clusters (Qualisys walking_hybrid), Rajagopal, numbered plates
              "#thigh1", "#thigh2", "#thigh3", "#thigh4", "#th1", "#th2", "#th3", "#th4",
              # OpenSim gait2392 / Hamner
              "#thighupper", "#thighfront", "#thighrear",
              # Helen Hayes (thigh wand), BTS
              "#bar1", "#knee1", "#kne1", "#kne2", "#suppat", "#knjntln",
              # Codamotion wands, Qualisys sports
              "#postfem", "#antfem", "#fle", "#fme", "#ftc", "#knee", "#knm", "#kne_med"],
    "shank": ["#kne", "#tib", "#shn", "#tiap", "#tiad", "#ank", "#mal", "#mall",
              "#shank1", "#shank2", "#shank3", "#shank4", "#sk1", "#sk2", "#sk3", "#sk4",
              "#tb1", "#tb2", "#tb3", "#sh1", "#sh2", "#sh3", "#sh4",
              "#shankupper", "#shankfront", "#shankrear",
              "#bar2", "#tubtib", "#posttib", "#anttib", "#ankle", "#fal", "#tam", "#ankm",
              "#knee"],
    "foot": ["#ank", "#hee", "#toe", "#mt5", "#fmh", "#vmh", "#heel", "#mt1", "#met", "#met1",
             "#cal", "#toetip", "#midfootsup", "#midfootlat", "#toelat", "#toemed",
             "#fcc", "#fm1", "#fm2", "#fm5", "#ft1", "#ft2", "#ft3", "#mal", "#mall"],
    # OpenSim / Rajagopal / Hamner upper limb
    "upper_arm_osim": ["#acromium", "#bicep", "#biceps", "#elbow", "#ua1", "#ua2", "#ua3",
                       "#lel", "#mel", "#shoulder", "#acr"],
    "forearm_osim": ["#elbow", "#forearm", "#wrist", "#wristmed", "#wristlat", "#fasuperior",
                     "#faradius", "#faulna", "#lel", "#mel"],
}
_CENTRAL = {
    "head": ["lfhd", "rfhd", "lbhd", "rbhd", "rtemple", "ltemple", "tophead", "head", "hf", "hb"],
    "thorax": ["c7", "t10", "clav", "strn", "rbak", "rbac", "sternum", "th12", "rclavicle",
               "lclavicle", "rcla", "lcla"],
    "pelvis": ["lasi", "rasi", "lpsi", "rpsi", "sacr", "sacrum", "lfwt", "rfwt", "lbwt", "rbwt",
               "vsacral", "s2", "lasis", "rasis", "lpsis", "rpsis", "lias", "rias", "lips", "rips",
               "lsacwand", "rsacwand", "sacr1", "rasi1", "lasi1", "pv1", "pv2", "pv3", "pv4"],
}


def _table() -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for name, members in _CENTRAL.items():
        out[name] = list(members)
    for name, members in _SIDED.items():
        seg = name.replace("_osim", "")
        for side in "lr":
            out.setdefault(f"{side}_{seg}", [])
            out[f"{side}_{seg}"] += [m.replace("#", side) for m in members]
    return out


#: segment name -> normalised marker names (see the comments above for the marker sets).
TABLE = _table()
_SEGMENTS_OF: dict[str, list[str]] = {}
for _seg, _names in TABLE.items():
    for _n in _names:
        if _seg not in _SEGMENTS_OF.setdefault(_n, []):
            _SEGMENTS_OF[_n].append(_seg)

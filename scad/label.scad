// morphshell SCAD library: seven-segment labels (no system font needed, so every
// machine renders them identically and a test can read them back from the STL).
include <params.scad>

// Function: seg7_segments()
// Usage:
//   segs = seg7_segments(ch);
// Description:
//   Lit segments of one character as a string over "abcdefgp" (a top, b upper
//   right, c lower right, d bottom, e lower left, f upper left, g middle,
//   p decimal point).  Knows 0-9, L, H, "-", "." and " ".
function seg7_segments(ch) =
    let(table = [["0", "abcdef"], ["1", "bc"], ["2", "abdeg"], ["3", "abcdg"], ["4", "bcfg"],
                 ["5", "acdfg"], ["6", "acdefg"], ["7", "abc"], ["8", "abcdefg"],
                 ["9", "abcdfg"], ["L", "def"], ["H", "bcefg"], ["-", "g"], [".", "p"],
                 [" ", ""]],
        hit = [for (e = table) if (e[0] == ch) e[1]])
    assert(len(hit) == 1, str("seg7: no glyph for character \"", ch, "\" (use 0-9 L H - . space)"))
    hit[0];

// Function: seg7_advance()
// Usage: w = seg7_advance(ch, size);
// Description: horizontal advance of one character (mm); a dot is narrow.
function seg7_advance(ch, size) = ch == "." ? 0.3 * size : 0.62 * size;

// Function: seg7_width()
// Usage: w = seg7_width(s, size);
// Description: total advance of a string (mm).
function seg7_width(s, size, i=0) =
    i >= len(s) ? 0 : seg7_advance(s[i], size) + seg7_width(s, size, i + 1);

// Function: seg7_rects()
// Usage:
//   rects = seg7_rects(s, [size], [stroke]);
// Description:
//   The label as data: list of [x0, y0, x1, y1] rectangles (mm), one per lit
//   segment, text starting at x = 0 with its baseline at y = 0 and cap height
//   `size`.  Each character occupies a cell 0.5 size wide (0.62 size advance).
// Arguments:
//   s = the text
//   size = cap height, mm. Default: 3
//   stroke = segment width, mm. Default: 0.5
function seg7_rects(s, size=3, stroke=0.5, i=0, x=0) =
    i >= len(s) ? [] :
    let(w = 0.5 * size, t = stroke, hh = size / 2,
        r = [["a", [0, size - t, w, size]], ["b", [w - t, hh, w, size]], ["c", [w - t, 0, w, hh]],
             ["d", [0, 0, w, t]], ["e", [0, 0, t, hh]], ["f", [0, hh, t, size]],
             ["g", [0, hh - t / 2, w, hh + t / 2]], ["p", [0, 0, t, t]]],
        segs = seg7_segments(s[i]),
        mine = [for (e = r) if (len(search(e[0], segs)) > 0 && search(e[0], segs)[0] != [])
                    [x + e[1][0], e[1][1], x + e[1][2], e[1][3]]])
    concat(mine, seg7_rects(s, size, stroke, i + 1, x + seg7_advance(s[i], size)));

// Module: seg7_text()
// Usage:
//   seg7_text(s, [size], [height], [stroke], [center]);
// Description:
//   Extruded seven-segment text: the rectangles of seg7_rects() raised by
//   `height` from z = 0.  With center = true the text is centred on the origin.
// Arguments:
//   s = text (0-9, L, H, "-", ".", " ")
//   size = cap height, mm. Default: 3
//   height = extrusion height, mm. Default: 0.3
//   stroke = segment width, mm. Default: 0.5
//   center = centre the text on the origin. Default: false
module seg7_text(s, size=3, height=0.3, stroke=0.5, center=false) {
    assert(is_string(s), str("seg7_text(): s must be a string, got ", s));
    assert(is_num(size) && size > 0 && is_num(stroke) && stroke > 0 && stroke < size / 3,
           str("seg7_text(): need size > 0 and 0 < stroke < size/3, got ", size, ", ", stroke));
    assert(is_num(height) && height > 0, str("seg7_text(): height must be > 0 mm, got ", height));
    shift = center ? [-(seg7_width(s, size) - 0.12 * size) / 2, -size / 2, 0] : [0, 0, 0];
    translate(shift)
        for (r = seg7_rects(s, size, stroke))
            translate([r[0], r[1], 0]) cube([r[2] - r[0], r[3] - r[1], height]);
}

#include "analysis/report_plots.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <set>
#include <sstream>

#include "analysis/report_json.h"

namespace idm::analysis {

std::vector<double> nice_ticks(double lo, double hi, int count) {
  if (!(hi > lo)) hi = lo + 1;
  const double raw = (hi - lo) / std::max(1, count);
  const double p = std::pow(10.0, std::floor(std::log10(raw)));
  double step = p;
  for (double m : {1.0, 2.0, 5.0, 10.0})
    if (m * p >= raw) {
      step = m * p;
      break;
    }
  std::vector<double> t;
  for (double v = std::ceil(lo / step - 1e-9) * step; v <= hi + 1e-9 * step; v += step)
    t.push_back(std::fabs(v) < 1e-9 * step ? 0.0 : v);
  return t;
}

std::string tick_label(double value, double step) {
  const int decimals = std::max(0, -static_cast<int>(std::floor(std::log10(step) + 1e-9)));
  char b[64];
  std::snprintf(b, sizeof b, "%.*f", decimals, std::fabs(value) < 0.5 * step ? 0.0 : value);
  return b;
}

namespace {

std::string fmt(const char* f, double v) {
  char b[64];
  std::snprintf(b, sizeof b, f, v);
  return b;
}

std::string esc(const std::string& s) {
  std::string o;
  for (char c : s) {
    if (c == '<')
      o += "&lt;";
    else if (c == '>')
      o += "&gt;";
    else if (c == '&')
      o += "&amp;";
    else
      o += c;
  }
  return o;
}

// The fill of a cell with no data (none recorded, or no value): grey with hatching, never a
// colour of the scale (white is a heat map's 0).
constexpr const char* kNoDataId = "idm-no-data";
const std::string kNoDataFill = std::string("url(#") + kNoDataId + ")";

struct Svg {
  std::ostringstream s;
  Svg(int w, int h) {
    s << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << w << "\" height=\"" << h
      << "\" viewBox=\"0 0 " << w << " " << h
      << "\" font-family=\"sans-serif\" font-size=\"12\">\n<defs><pattern id=\"" << kNoDataId
      << "\" width=\"6\" height=\"6\" patternUnits=\"userSpaceOnUse\" "
         "patternTransform=\"rotate(45)\"><rect width=\"6\" height=\"6\" fill=\"#e0e0e0\"/>"
         "<line x1=\"0\" y1=\"0\" x2=\"0\" y2=\"6\" stroke=\"#9a9a9a\" stroke-width=\"2\"/>"
         "</pattern></defs>\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
  }
  void text(double x, double y, const std::string& t, const char* anchor = "middle", int size = 12,
            double rotate = 0) {
    s << "<text x=\"" << fmt("%.1f", x) << "\" y=\"" << fmt("%.1f", y) << "\" text-anchor=\""
      << anchor << "\" font-size=\"" << size << "\"";
    if (rotate != 0)
      s << " transform=\"rotate(" << rotate << " " << fmt("%.1f", x) << " " << fmt("%.1f", y)
        << ")\"";
    s << ">" << esc(t) << "</text>\n";
  }
  void rect(double x, double y, double w, double h, const std::string& fill,
            const std::string& stroke = "none") {
    s << "<rect x=\"" << fmt("%.1f", x) << "\" y=\"" << fmt("%.1f", y) << "\" width=\""
      << fmt("%.1f", w) << "\" height=\"" << fmt("%.1f", h) << "\" fill=\"" << fill
      << "\" stroke=\"" << stroke << "\"/>\n";
  }
  void line(double x1, double y1, double x2, double y2, const std::string& c, double w = 1) {
    s << "<line x1=\"" << fmt("%.1f", x1) << "\" y1=\"" << fmt("%.1f", y1) << "\" x2=\""
      << fmt("%.1f", x2) << "\" y2=\"" << fmt("%.1f", y2) << "\" stroke=\"" << c
      << "\" stroke-width=\"" << w << "\"/>\n";
  }
  void circle(double x, double y, double r, const std::string& fill,
              const std::string& stroke = "none") {
    s << "<circle cx=\"" << fmt("%.1f", x) << "\" cy=\"" << fmt("%.1f", y) << "\" r=\""
      << fmt("%.1f", r) << "\" fill=\"" << fill << "\" stroke=\"" << stroke << "\"/>\n";
  }
  std::string done() { return s.str() + "</svg>\n"; }
};

const char* region_colour(model::Region r) {
  switch (r) {
    case model::Region::Cutoff:
      return "#d9d9d9";
    case model::Region::OneStep:
      return "#74c476";
    case model::Region::MultiStep:
      return "#fd8d3c";
  }
  return "white";
}

const char* kColours[] = {"#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
                          "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf"};

std::vector<double> sorted_unique(const std::vector<double>& v) {
  std::set<double> s(v.begin(), v.end());
  return {s.begin(), s.end()};
}

std::vector<double> keys(const SweepCells& sweep, double CellKey::*field, int direction = 0) {
  std::vector<double> v;
  for (const Cell& c : sweep.cells)
    if (direction == 0 || (direction < 0) == (c.key.duty < 0.5)) v.push_back(c.key.*field);
  return sorted_unique(v);
}

std::size_t index_of(const std::vector<double>& v, double x) {
  return static_cast<std::size_t>(std::lower_bound(v.begin(), v.end(), x) - v.begin());
}

// One (frequency x duty) panel of coloured cells for one stroke and direction (-1: duty < 0.5,
// +1: duty > 0.5, 0: both) at (x0, y0).
template <class Colour>
void panel(Svg& g, const SweepCells& sweep, double stroke, int direction, double x0, double y0,
           double w, double h, const std::string& title, Colour colour) {
  const std::vector<double> fr = keys(sweep, &CellKey::freq_hz),
                            du = keys(sweep, &CellKey::duty, direction);
  const double cw = w / fr.size(), ch = h / std::max<std::size_t>(1, du.size());
  g.rect(x0, y0, w, h, kNoDataFill, "white");  // positions of the grid no cell covers
  for (std::size_t c = 0; c < sweep.cells.size(); ++c) {
    const CellKey& k = sweep.cells[c].key;
    if (k.stroke_m != stroke || (direction != 0 && (direction < 0) != (k.duty < 0.5))) continue;
    const double x = x0 + cw * index_of(fr, k.freq_hz),
                 y = y0 + h - ch * (index_of(du, k.duty) + 1);
    g.rect(x, y, cw, ch, colour(c), "white");
  }
  g.text(x0 + w / 2, y0 - 8, title, "middle", 12);
  for (std::size_t i = 0; i < fr.size(); ++i)
    if (fr.size() <= 12 || i % 2 == 0)
      g.text(x0 + cw * (i + 0.5), y0 + h + 14, fmt("%g", fr[i]), "middle", 10);
  for (std::size_t j = 0; j < du.size(); ++j)
    if (du.size() <= 20 || j % 2 == 0)
      g.text(x0 - 4, y0 + h - ch * (j + 0.5) + 4, fmt("%g", du[j]), "end", 10);
  g.text(x0 + w / 2, y0 + h + 30, "frequency (Hz)");
  g.text(x0 - 36, y0 + h / 2, "duty ratio", "middle", 12, -90);
}

std::vector<int> directions_of(const SweepCells& sweep) {
  bool fwd = false, rev = false;
  for (const Cell& c : sweep.cells) (c.key.duty < 0.5 ? fwd : rev) = true;
  std::vector<int> d;
  if (fwd) d.push_back(-1);
  if (rev) d.push_back(1);
  return d;
}

std::string heat(double r) {
  if (!std::isfinite(r)) return kNoDataFill;
  // white at 0, yellow at the significance threshold, dark red at 100 and beyond (log scale)
  const double t = std::clamp(std::log10(1 + r) / 2.0, 0.0, 1.0);
  const int red = static_cast<int>(255 - 120 * std::max(0.0, t - 0.3) / 0.7);
  const int green = static_cast<int>(255 * (1 - t));
  const int blue = static_cast<int>(255 * std::max(0.0, 1 - 3 * t));
  char b[16];
  std::snprintf(b, sizeof b, "#%02x%02x%02x", red, green, blue);
  return b;
}

// The legend's swatch for cells without data.
void no_data_legend(Svg& g, double x, double y) {
  g.rect(x, y, 16, 16, kNoDataFill, "#888");
  g.text(x + 22, y + 12, "no data", "start", 10);
}

// Step axes: micrometres when the steps reach one, else nanometres.
struct StepAxis {
  double scale = 1e6;
  const char* unit = "um";
};

}  // namespace

std::string steps_svg(const SweepCells& sweep, const Diagnosis& d) {
  const std::vector<double> strokes = keys(sweep, &CellKey::stroke_m),
                            fr = keys(sweep, &CellKey::freq_hz);
  double lo = 0, hi = 0;
  for (std::size_t c = 0; c < sweep.cells.size(); ++c)
    for (double v :
         {d.baseline.test.cells[c].measured_step_m, d.after.test.cells[c].model_step_m}) {
      lo = std::min(lo, v);
      hi = std::max(hi, v);
    }
  StepAxis ax;
  if (std::max(-lo, hi) < 1e-6) {
    ax.scale = 1e9;
    ax.unit = "nm";
  }
  const std::vector<double> yt = nice_ticks(lo * ax.scale, hi * ax.scale, 6);
  const double ylo = std::min(yt.front(), lo * ax.scale), yhi = std::max(yt.back(), hi * ax.scale);
  const double W = 380, H = 300, gapx = 90, X0 = 80, top = 60;
  Svg g(static_cast<int>(X0 + 2 * (W + gapx) + 110),
        static_cast<int>(top + strokes.size() * (H + 80) + 20));
  g.text(20, 24,
         "Steady step against duty, one line per frequency: measured (mean of all trials) and the "
         "model "
         "after the diagnosis; ringed: cells whose gap is significant",
         "start", 13);
  for (std::size_t r = 0; r < strokes.size(); ++r) {
    const double y0 = top + r * (H + 80);
    for (int side = 0; side < 2; ++side) {
      const double x0 = X0 + side * (W + gapx);
      auto px = [&](double duty) { return x0 + W * duty; };
      auto py = [&](double v) { return y0 + H - H * (v - ylo) / (yhi - ylo); };
      g.rect(x0, y0, W, H, "none", "#444");
      for (double t : nice_ticks(0, 1, 10)) {
        g.line(px(t), y0 + H, px(t), y0 + H + 4, "#444");
        g.text(px(t), y0 + H + 16, tick_label(t, 0.1), "middle", 10);
      }
      const double ystep = yt.size() > 1 ? yt[1] - yt[0] : 1;
      for (double t : yt) {
        g.line(x0 - 4, py(t), x0, py(t), "#444");
        g.text(x0 - 6, py(t) + 4, tick_label(t, ystep), "end", 10);
      }
      if (ylo < 0 && yhi > 0) g.line(x0, py(0), x0 + W, py(0), "#bbb");
      g.text(x0 + W / 2, y0 - 8,
             std::string(side == 0 ? "measured" : "model after the diagnosis") + ", stroke " +
                 fmt("%.4g", strokes[r] * 1e6) + " um",
             "middle", 12);
      g.text(x0 + W / 2, y0 + H + 34, "duty ratio (1)");
      g.text(x0 - 50, y0 + H / 2, std::string("steady step (") + ax.unit + " per cycle)", "middle",
             12, -90);
      for (std::size_t i = 0; i < fr.size(); ++i) {
        const char* col = kColours[i % 10];
        std::vector<std::pair<double, double>> pts;
        for (std::size_t c = 0; c < sweep.cells.size(); ++c) {
          const CellKey& k = sweep.cells[c].key;
          if (k.stroke_m != strokes[r] || k.freq_hz != fr[i]) continue;
          const double v = (side == 0 ? d.baseline.test.cells[c].measured_step_m
                                      : d.after.test.cells[c].model_step_m) *
                           ax.scale;
          pts.push_back({k.duty, v});
          if (side == 0) {
            g.circle(px(k.duty), py(v), 3, col);
            if (d.baseline.test.cells[c].significant)
              g.circle(px(k.duty), py(v), 6.5, "none", "#d62728");
          }
        }
        std::sort(pts.begin(), pts.end());
        for (std::size_t k = 1; k < pts.size(); ++k)
          if ((pts[k - 1].first < 0.5) == (pts[k].first < 0.5))
            g.line(px(pts[k - 1].first), py(pts[k - 1].second), px(pts[k].first), py(pts[k].second),
                   col, side == 0 ? 1.0 : 1.8);
      }
    }
  }
  for (std::size_t i = 0; i < fr.size(); ++i) {
    g.rect(X0 + 2 * (W + gapx) - 50, top + 10 + 20 * i, 12, 12, kColours[i % 10]);
    g.text(X0 + 2 * (W + gapx) - 32, top + 21 + 20 * i, fmt("%g Hz", fr[i]), "start");
  }
  return g.done();
}

std::string regions_svg(const SweepCells& sweep, const Diagnosis& d) {
  const std::vector<double> strokes = keys(sweep, &CellKey::stroke_m);
  const double pw = 260, ph = 260;
  Svg g(static_cast<int>(3 * (pw + 80) + 40), static_cast<int>(strokes.size() * (ph + 80) + 70));
  g.text(20, 22,
         "Region maps: measured (committee vote of the trials), impulse model, model after the "
         "diagnosis",
         "start", 14);
  for (std::size_t r = 0; r < strokes.size(); ++r) {
    const double y = 60 + r * (ph + 80);
    const std::string st = " (stroke " + fmt("%.4g", strokes[r] * 1e6) + " um)";
    panel(g, sweep, strokes[r], 0, 70, y, pw, ph, "measured" + st,
          [&](std::size_t c) { return region_colour(sweep.cells[c].measured_region); });
    panel(g, sweep, strokes[r], 0, 70 + pw + 80, y, pw, ph, "impulse model" + st,
          [&](std::size_t c) { return region_colour(d.baseline.test.cells[c].model_region); });
    panel(g, sweep, strokes[r], 0, 70 + 2 * (pw + 80), y, pw, ph, "after diagnosis" + st,
          [&](std::size_t c) { return region_colour(d.after.test.cells[c].model_region); });
  }
  double lx = 600;
  for (model::Region reg :
       {model::Region::Cutoff, model::Region::OneStep, model::Region::MultiStep}) {
    g.rect(lx, 30, 12, 12, region_colour(reg));
    g.text(lx + 16, 40, model::region_name(reg), "start");
    lx += 100;
  }
  no_data_legend(g, lx, 28);
  return g.done();
}

std::string cell_map_svg(const SweepCells& sweep, const std::vector<double>& values,
                         const std::string& title, const std::string& legend,
                         const std::string& when_empty) {
  const std::vector<double> strokes = keys(sweep, &CellKey::stroke_m);
  const std::vector<int> dirs = directions_of(sweep);
  const double pw = 260, ph = 220;
  const std::size_t panels = strokes.size() * dirs.size();
  const bool empty =
      !when_empty.empty() && std::none_of(values.begin(), values.end(),
                                          [](double v) { return std::isfinite(v) && v > 0; });
  Svg g(static_cast<int>(panels * (pw + 90) + 150), static_cast<int>(ph + 130));
  g.text(20, 22,
         title + " (colour: " + legend + ", in " + kGapUnit + "; 1 = the noise, 3 = significant)",
         "start", 13);
  std::size_t k = 0;
  for (double s : strokes)
    for (int dir : dirs) {
      panel(g, sweep, s, dir, 70 + k * (pw + 90), 60, pw, ph,
            "stroke " + fmt("%.4g", s * 1e6) + " um, duty " + (dir < 0 ? "< 0.5" : "> 0.5"),
            [&](std::size_t c) { return heat(values[c]); });
      ++k;
    }
  const double lx = 70 + panels * (pw + 90) - 20;
  for (int i = 0; i <= 4; ++i) {
    const double v = i == 0 ? 0.0 : std::pow(10.0, (i - 1) * 0.5 + 0.5);
    g.rect(lx, 70 + 24 * i, 16, 16, heat(v), "#888");
    g.text(lx + 22, 82 + 24 * i, fmt("%.3g", v) + " " + kGapUnit, "start", 10);
  }
  no_data_legend(g, lx, 70 + 24 * 5);
  if (empty) {
    const double width = panels * (pw + 90) - 90;
    g.rect(70 + width / 2 - 190, 60 + ph / 2 - 22, 380, 44, "white", "#444");
    g.text(70 + width / 2, 60 + ph / 2 + 5, when_empty, "middle", 15);
  }
  return g.done();
}

std::string ranking_svg(const Diagnosis& d) {
  const double X0 = 170, W = 420, rowh = 26;
  Svg g(760, static_cast<int>(80 + rowh * (d.candidates.size() + d.not_identifiable.size())));
  g.text(20, 22,
         "Each effect added alone: shrink of the held-out gap (from " + fmt("%.3g", d.gap_before) +
             " " + kGapUnit + ")",
         "start", 14);
  auto px = [&](double s) { return X0 + W * std::clamp(s, 0.0, 1.0); };
  for (double t : nice_ticks(0, 100, 4)) {
    g.line(px(t / 100), 40, px(t / 100), 50 + rowh * d.candidates.size(), "#ddd");
    g.text(px(t / 100), 38, tick_label(t, 25) + " %", "middle", 10);
  }
  double y = 50;
  for (const SetFit& c : d.candidates) {
    const std::string name = c.effects.front().name;
    const bool chosen = std::any_of(d.chosen.begin(), d.chosen.end(),
                                    [&](const model::EffectSpec& e) { return e.name == name; });
    g.text(X0 - 8, y + 16, name, "end");
    g.rect(X0, y + 4, std::max(0.0, px(c.shrink) - X0), rowh - 8,
           chosen ? "#2b8cbe" : (c.plausible ? "#a6bddb" : "#eeeeee"), "#666");
    g.text(px(std::max(0.0, c.shrink)) + 6, y + 16,
           fmt("%.1f %%", 100 * c.shrink) + " (gap " + fmt("%.3g", c.gap) + " " + kGapUnit + ")" +
               (c.plausible ? "" : " implausible") + (chosen ? " named" : ""),
           "start", 11);
    y += rowh;
  }
  for (const NotIdentifiable& n : d.not_identifiable) {
    g.text(X0 - 8, y + 16, n.effect, "end");
    g.text(X0, y + 16, "not identifiable: needs " + n.needs, "start", 11);
    y += rowh;
  }
  return g.done();
}

namespace {

const char* kStyle =
    "body{font-family:sans-serif;line-height:1.45;max-width:72em;margin:0 auto;padding:0 1em 2em;"
    "color:#222}\n"
    "h1{font-size:1.5em}h2{font-size:1.2em;border-bottom:1px solid #ccc;margin-top:2em}\n"
    "nav a{margin-right:1em}\n"
    "pre{white-space:pre-wrap;overflow-wrap:anywhere;background:#f6f6f6;padding:.6em}\n"
    "figure{margin:1em 0}figcaption{font-size:.9em;color:#555}\n"
    "svg{max-width:100%;height:auto;display:block}\n"
    "table{border-collapse:collapse;margin:.5em 0}\n"
    "th,td{border:1px solid #ccc;padding:.2em .6em;vertical-align:top;text-align:left}\n"
    "td.n{text-align:right;white-space:nowrap}\n"
    ".wrap{overflow-wrap:anywhere}\n";

std::string row(const std::string& key, const std::string& value) {
  return "<tr><th>" + esc(key) + "</th><td>" + esc(value) + "</td></tr>\n";
}

std::string gap_text(double gap) {
  return fmt("%.3g", gap) + " " + kGapUnit;
}

// The key figures, each with its unit.
std::string facts_table(const SweepCells& sweep, const Diagnosis& d) {
  std::size_t trials = 0;
  for (const Cell& c : sweep.cells) trials += c.train.size() + c.test.size();
  std::string names;
  for (const model::EffectSpec& e : d.chosen) names += (names.empty() ? "" : " + ") + e.name;
  std::string t = "<table>\n";
  t += row("diagnosis", d.named
                            ? names
                            : (d.unexplained.significant ? "nothing named: the gap is unexplained"
                                                         : "no significant gap to explain"));
  t += row("cells, trials",
           std::to_string(sweep.cells.size()) + " cells, " + std::to_string(trials) + " trials");
  t += row("reading noise", fmt("%.2g", sweep.reading_sd_m * 1e9) + " nm (one count " +
                                fmt("%.4g", sweep.resolution_m * 1e9) + " nm)");
  t += row("held-out gap of the impulse model", gap_text(d.gap_before));
  if (d.named)
    t += row("held-out gap after the diagnosis",
             gap_text(d.gap_after) + " (shrink " + fmt("%.1f", 100 * d.shrink) + " %)");
  t += row("unexplained", std::string(d.unexplained.significant ? "significant: " : "no: ") +
                              d.unexplained.summary);
  t += row("unit of the gap", std::string(kGapUnit) +
                                  ": the standard uncertainty of a cell's measured mean step and "
                                  "spread; about 1 is within the noise, 3 significant");
  return t + "</table>\n";
}

// Each effect alone: held-out gap, shrink, parameters, intervals.
std::string candidates_table(const Diagnosis& d) {
  std::string t = "<table>\n<tr><th>effect</th><th>held-out gap (" + std::string(kGapUnit) +
                  ")</th><th>shrink (%)</th><th>fitted parameters (unit in the name)</th>"
                  "<th>95 % intervals (held-out)</th><th>note</th></tr>\n";
  for (std::size_t i = 0; i < d.candidates.size(); ++i) {
    const SetFit& c = d.candidates[i];
    std::string params, intervals;
    for (const model::EffectSpec& e : c.effects)
      for (const auto& [k, v] : e.params)
        if (k != "correlation_m" && k != "mean_shift" && !(k == "slew_rate_m_s" && v == 0))
          params += (params.empty() ? "" : ", ") + k + " = " + model::format_number(v, 4);
    if (i < d.intervals.size())
      for (const ParameterIntervals& pi : d.intervals[i])
        for (const ParameterInterval& p : pi.params)
          intervals += (intervals.empty() ? "" : ", ") + p.param + " " +
                       model::format_number(p.lo, 4) + " to " + model::format_number(p.hi, 4) +
                       (p.limited_by_range ? " (range)" : "");
    t += "<tr><td>" + esc(c.effects.front().name) + "</td><td class=\"n\">" + fmt("%.3g", c.gap) +
         "</td><td class=\"n\">" + fmt("%.1f", 100 * c.shrink) + "</td><td class=\"wrap\">" +
         esc(params) + "</td><td class=\"wrap\">" + esc(intervals) + "</td><td class=\"wrap\">" +
         esc(c.plausible ? "" : "implausible: " + c.note) + "</td></tr>\n";
  }
  for (const NotIdentifiable& n : d.not_identifiable)
    t += "<tr><td>" + esc(n.effect) +
         "</td><td colspan=\"5\">not identifiable from this data: needs " + esc(n.needs) +
         "</td></tr>\n";
  return t + "</table>\n";
}

// The cells and the trials the diagnosis left out, and why; "" when none.
std::string left_out_section(const SweepCells& sweep) {
  const std::string progress = progress_summary(sweep);
  if (sweep.damaged.empty() && progress.empty()) return "";
  std::string h = "<section id=\"left-out\"><h2>Left out</h2>\n";
  if (!progress.empty()) h += "<p>" + esc(progress) + "</p>\n";
  if (!sweep.damaged.empty()) {
    h += "<table>\n<tr><th>trial file</th><th>why it was left out</th></tr>\n";
    for (const LeftOutTrial& t : sweep.damaged)
      h += "<tr><td class=\"wrap\">" + esc(t.file) + "</td><td class=\"wrap\">" + esc(t.why) +
           "</td></tr>\n";
    h += "</table>\n";
  }
  return h + "</section>\n";
}

// The caption links the plot's own file, written next to report.html.
std::string figure(const std::string& svg, const std::string& caption, const std::string& file) {
  return "<figure>" + svg + "<figcaption>" + esc(caption) + " (<a href=\"" + esc(file) + "\">" +
         esc(file) + "</a>)</figcaption></figure>\n";
}

// The plots of the report by file name, in the order the page shows them.
struct Plot {
  const char* file;
  std::string svg;
  const char* caption;
};

std::vector<Plot> report_plots(const SweepCells& sweep, const Diagnosis& d) {
  std::vector<double> before, after, footprint, spread, departure;
  for (std::size_t c = 0; c < sweep.cells.size(); ++c) {
    before.push_back(d.baseline.test.cells[c].residual);
    after.push_back(d.after.test.cells[c].residual);
    footprint.push_back(d.where.cells[c].effect_gap);
    spread.push_back(d.where.cells[c].spread_excess);
    departure.push_back(d.where.cells[c].departure);
  }
  return {
      {"effect_gap.svg",
       cell_map_svg(sweep, footprint, "Where the named effects act (effect_gap)",
                    "the model with them against without", "no effect named: no footprint"),
       "Where the named effects act"},
      {"spread_excess.svg",
       cell_map_svg(sweep, spread, "Trial-to-trial spread beyond the model's", "spread_excess",
                    "no cell shows a spread excess"),
       "Spread beyond the model's"},
      {"gap_before.svg",
       cell_map_svg(sweep, before, "The gap of the impulse model, cell by cell",
                    "held-out residual"),
       "The gap of the impulse model, cell by cell"},
      {"gap_after.svg",
       cell_map_svg(sweep, after, "What is left after the diagnosis", "held-out residual"),
       "What is left after the diagnosis"},
      {"departure.svg",
       cell_map_svg(sweep, departure, "Where the stage departs from stage.yaml's",
                    "held-out residual at stage.yaml's mu, alpha 1"),
       "Where the stage departs from its description"},
      {"steps.svg", steps_svg(sweep, d), "Step size against duty"},
      {"regions.svg", regions_svg(sweep, d), "Region maps"},
      {"ranking.svg", ranking_svg(d), "Which effect: each alone"},
  };
}

std::string report_html(const SweepCells& sweep, const Diagnosis& d, const std::string& summary,
                        const std::vector<Plot>& plots) {
  auto fig = [&](const char* file) {
    for (const Plot& p : plots)
      if (std::string(p.file) == file) return figure(p.svg, p.caption, p.file);
    return std::string();
  };
  std::ostringstream h;
  h << "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
    << "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
    << "<title>idm-gap: " << esc(sweep.name) << "</title>\n<style>\n"
    << kStyle << "</style></head>\n<body>\n<h1>Sim-to-real gap: " << esc(sweep.name) << "</h1>\n"
    << "<nav><a href=\"#summary\">Summary</a><a href=\"#which\">Which effect</a>"
    << "<a href=\"#where\">Where</a><a href=\"#steps\">Steps</a><a href=\"#regions\">Regions</a>"
    << "<a href=\"#text\">Text</a></nav>\n"
    << "<section id=\"summary\"><h2>Summary</h2>\n"
    << facts_table(sweep, d) << "</section>\n"
    << left_out_section(sweep) << "<section id=\"which\"><h2>Which effect</h2>\n"
    << candidates_table(d) << fig("ranking.svg") << "</section>\n"
    << "<section id=\"where\"><h2>Where</h2>\n<p>" << esc(d.where.summary) << "</p>\n"
    << fig("effect_gap.svg") << fig("spread_excess.svg") << fig("gap_before.svg")
    << fig("gap_after.svg") << fig("departure.svg") << "</section>\n"
    << "<section id=\"steps\"><h2>Step size against duty</h2>\n"
    << fig("steps.svg") << "</section>\n<section id=\"regions\"><h2>Region maps</h2>\n"
    << fig("regions.svg") << "</section>\n<section id=\"text\"><h2>Text summary</h2>\n<pre>"
    << esc(summary) << "</pre></section>\n</body></html>\n";
  return h.str();
}

}  // namespace

std::string write_report(const SweepCells& sweep, const Diagnosis& d, const std::string& summary,
                         const std::string& dir) {
  std::filesystem::create_directories(dir);
  const std::filesystem::path p(dir);
  const std::vector<Plot> plots = report_plots(sweep, d);
  for (const Plot& plot : plots) write_file_atomic((p / plot.file).string(), plot.svg);
  std::string html = (p / "report.html").string();
  write_file_atomic(html, report_html(sweep, d, summary, plots));
  return html;
}

}  // namespace idm::analysis

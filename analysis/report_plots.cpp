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

struct Svg {
  std::ostringstream s;
  Svg(int w, int h) {
    s << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << w << "\" height=\"" << h
      << "\" viewBox=\"0 0 " << w << " " << h
      << "\" font-family=\"sans-serif\" font-size=\"12\">\n<rect width=\"100%\" height=\"100%\" "
         "fill=\"white\"/>\n";
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
  // white at 0, yellow at the significance threshold, dark red at 100 and beyond (log scale)
  const double t = std::clamp(std::log10(1 + r) / 2.0, 0.0, 1.0);
  const int red = static_cast<int>(255 - 120 * std::max(0.0, t - 0.3) / 0.7);
  const int green = static_cast<int>(255 * (1 - t));
  const int blue = static_cast<int>(255 * std::max(0.0, 1 - 3 * t));
  char b[16];
  std::snprintf(b, sizeof b, "#%02x%02x%02x", red, green, blue);
  return b;
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
  return g.done();
}

std::string cell_map_svg(const SweepCells& sweep, const std::vector<double>& values,
                         const std::string& title, const std::string& legend) {
  const std::vector<double> strokes = keys(sweep, &CellKey::stroke_m);
  const std::vector<int> dirs = directions_of(sweep);
  const double pw = 260, ph = 220;
  const std::size_t panels = strokes.size() * dirs.size();
  Svg g(static_cast<int>(panels * (pw + 90) + 150), static_cast<int>(ph + 130));
  g.text(20, 22, title + " (colour: " + legend + "; 1 = the noise, 3 = significant)", "start", 13);
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
    g.text(lx + 22, 82 + 24 * i, fmt("%.3g", v), "start", 10);
  }
  return g.done();
}

std::string ranking_svg(const Diagnosis& d) {
  const double X0 = 170, W = 420, rowh = 26;
  Svg g(760, static_cast<int>(80 + rowh * (d.candidates.size() + d.not_identifiable.size())));
  g.text(20, 22,
         "Each effect added alone: shrink of the held-out gap (from " + fmt("%.3g", d.gap_before) +
             ")",
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
           fmt("%.1f %%", 100 * c.shrink) + " (gap " + fmt("%.3g", c.gap) + ")" +
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

std::string write_report(const SweepCells& sweep, const Diagnosis& d, const std::string& summary,
                         const std::string& dir) {
  std::filesystem::create_directories(dir);
  const std::filesystem::path p(dir);
  std::vector<double> before, after, footprint, spread, departure;
  for (std::size_t c = 0; c < sweep.cells.size(); ++c) {
    before.push_back(d.baseline.test.cells[c].residual);
    after.push_back(d.after.test.cells[c].residual);
    footprint.push_back(d.where.cells[c].effect_gap);
    spread.push_back(d.where.cells[c].spread_excess);
    departure.push_back(d.where.cells[c].departure);
  }
  write_file_atomic((p / "steps.svg").string(), steps_svg(sweep, d));
  write_file_atomic((p / "regions.svg").string(), regions_svg(sweep, d));
  write_file_atomic((p / "gap_before.svg").string(),
                    cell_map_svg(sweep, before, "The gap of the impulse model, cell by cell",
                                 "held-out residual"));
  write_file_atomic((p / "effect_gap.svg").string(),
                    cell_map_svg(sweep, footprint, "Where the named effects act (effect_gap)",
                                 "the model with them against without"));
  write_file_atomic(
      (p / "spread_excess.svg").string(),
      cell_map_svg(sweep, spread, "Trial-to-trial spread beyond the model's", "spread_excess"));
  write_file_atomic((p / "departure.svg").string(),
                    cell_map_svg(sweep, departure, "Where the stage departs from stage.yaml's",
                                 "held-out residual at stage.yaml's mu, alpha 1"));
  write_file_atomic(
      (p / "gap_after.svg").string(),
      cell_map_svg(sweep, after, "What is left after the diagnosis", "held-out residual"));
  write_file_atomic((p / "ranking.svg").string(), ranking_svg(d));
  std::ostringstream h;
  h << "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>idm-gap: " << esc(sweep.name)
    << "</title></head>\n<body style=\"font-family:sans-serif;max-width:1300px\">\n<h1>Sim-to-real "
       "gap: "
    << esc(sweep.name) << "</h1>\n<pre style=\"white-space:pre-wrap\">" << esc(summary)
    << "</pre>\n"
    << "<h2>Step size against duty</h2><img src=\"steps.svg\" alt=\"steps\">\n"
    << "<h2>Where the named effects act</h2><img src=\"effect_gap.svg\" alt=\"effect gap\">\n"
    << "<h2>Spread beyond the model's</h2><img src=\"spread_excess.svg\" alt=\"spread excess\">\n"
    << "<h2>The gap, cell by cell</h2><img src=\"gap_before.svg\" alt=\"gap before\"><br>"
    << "<img src=\"gap_after.svg\" alt=\"gap after\">\n"
    << "<h2>Where the stage departs from its description</h2><img src=\"departure.svg\" "
       "alt=\"departure\">\n"
    << "<h2>Region maps</h2><img src=\"regions.svg\" alt=\"region maps\">\n"
    << "<h2>Which effect</h2><img src=\"ranking.svg\" alt=\"ranking\">\n</body></html>\n";
  std::string html = (p / "report.html").string();
  write_file_atomic(html, h.str());
  return html;
}

}  // namespace idm::analysis

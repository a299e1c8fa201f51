#include "analysis/report_plots.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <set>
#include <sstream>

#include "analysis/report_json.h"

namespace idm::analysis {

namespace {

std::string fmt(const char* f, double v) {
  char b[64];
  std::snprintf(b, sizeof b, f, v);
  return b;
}

std::string esc(const std::string& s) {
  std::string o;
  for (char c : s) {
    if (c == '<') o += "&lt;";
    else if (c == '>') o += "&gt;";
    else if (c == '&') o += "&amp;";
    else o += c;
  }
  return o;
}

struct Svg {
  std::ostringstream s;
  Svg(int w, int h) {
    s << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << w << "\" height=\"" << h << "\" viewBox=\"0 0 " << w
      << " " << h << "\" font-family=\"sans-serif\" font-size=\"12\">\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
  }
  void text(double x, double y, const std::string& t, const char* anchor = "middle", int size = 12, double rotate = 0) {
    s << "<text x=\"" << fmt("%.1f", x) << "\" y=\"" << fmt("%.1f", y) << "\" text-anchor=\"" << anchor
      << "\" font-size=\"" << size << "\"";
    if (rotate != 0) s << " transform=\"rotate(" << rotate << " " << fmt("%.1f", x) << " " << fmt("%.1f", y) << ")\"";
    s << ">" << esc(t) << "</text>\n";
  }
  void rect(double x, double y, double w, double h, const std::string& fill, const std::string& stroke = "none") {
    s << "<rect x=\"" << fmt("%.1f", x) << "\" y=\"" << fmt("%.1f", y) << "\" width=\"" << fmt("%.1f", w)
      << "\" height=\"" << fmt("%.1f", h) << "\" fill=\"" << fill << "\" stroke=\"" << stroke << "\"/>\n";
  }
  void line(double x1, double y1, double x2, double y2, const std::string& c, double w = 1) {
    s << "<line x1=\"" << fmt("%.1f", x1) << "\" y1=\"" << fmt("%.1f", y1) << "\" x2=\"" << fmt("%.1f", x2)
      << "\" y2=\"" << fmt("%.1f", y2) << "\" stroke=\"" << c << "\" stroke-width=\"" << w << "\"/>\n";
  }
  std::string done() { return s.str() + "</svg>\n"; }
};

const char* region_colour(model::Region r) {
  switch (r) {
    case model::Region::Cutoff: return "#d9d9d9";
    case model::Region::OneStep: return "#74c476";
    case model::Region::MultiStep: return "#fd8d3c";
  }
  return "white";
}

std::vector<double> sorted_unique(const SweepCells& sweep, double CellKey::*field) {
  std::set<double> v;
  for (const Cell& c : sweep.cells) v.insert(c.key.*field);
  return {v.begin(), v.end()};
}

std::size_t index_of(const std::vector<double>& v, double x) {
  return static_cast<std::size_t>(std::lower_bound(v.begin(), v.end(), x) - v.begin());
}

// One (frequency x duty) panel of coloured cells at (x0, y0); colour from `colour(cell index)`.
template <class Colour>
void panel(Svg& g, const SweepCells& sweep, double stroke, double x0, double y0, double w, double h,
           const std::string& title, Colour colour) {
  const std::vector<double> fr = sorted_unique(sweep, &CellKey::freq_hz), du = sorted_unique(sweep, &CellKey::duty);
  const double cw = w / fr.size(), ch = h / du.size();
  for (std::size_t c = 0; c < sweep.cells.size(); ++c) {
    const CellKey& k = sweep.cells[c].key;
    if (k.stroke_m != stroke) continue;
    const double x = x0 + cw * index_of(fr, k.freq_hz), y = y0 + h - ch * (index_of(du, k.duty) + 1);
    g.rect(x, y, cw, ch, colour(c), "white");
  }
  g.text(x0 + w / 2, y0 - 8, title, "middle", 13);
  for (std::size_t i = 0; i < fr.size(); ++i)
    if (fr.size() <= 12 || i % 2 == 0) g.text(x0 + cw * (i + 0.5), y0 + h + 14, fmt("%g", fr[i]), "middle", 10);
  for (std::size_t j = 0; j < du.size(); ++j)
    if (du.size() <= 20 || j % 2 == 0) g.text(x0 - 4, y0 + h - ch * (j + 0.5) + 4, fmt("%g", du[j]), "end", 10);
  g.text(x0 + w / 2, y0 + h + 30, "frequency (Hz)");
  g.text(x0 - 36, y0 + h / 2, "duty ratio", "middle", 12, -90);
}

}  // namespace

std::string regions_svg(const SweepCells& sweep, const Diagnosis& d) {
  const std::vector<double> strokes = sorted_unique(sweep, &CellKey::stroke_m);
  const double pw = 260, ph = 260;
  Svg g(static_cast<int>(3 * (pw + 80) + 40), static_cast<int>(strokes.size() * (ph + 80) + 70));
  g.text(20, 22, "Region maps: measured (committee vote of the trials), impulse model, model after the diagnosis", "start", 14);
  for (std::size_t r = 0; r < strokes.size(); ++r) {
    const double y = 60 + r * (ph + 80);
    const std::string st = " (stroke " + fmt("%.4g", strokes[r] * 1e6) + " um)";
    panel(g, sweep, strokes[r], 70, y, pw, ph, "measured" + st,
          [&](std::size_t c) { return region_colour(sweep.cells[c].measured_region); });
    panel(g, sweep, strokes[r], 70 + pw + 80, y, pw, ph, "impulse model" + st,
          [&](std::size_t c) { return region_colour(d.baseline.cells[c].model_region); });
    panel(g, sweep, strokes[r], 70 + 2 * (pw + 80), y, pw, ph, "after diagnosis" + st,
          [&](std::size_t c) { return region_colour(d.after.cells[c].model_region); });
  }
  const double ly = 40;
  double lx = 600;
  for (model::Region reg : {model::Region::Cutoff, model::Region::OneStep, model::Region::MultiStep}) {
    g.rect(lx, ly - 10, 12, 12, region_colour(reg));
    g.text(lx + 16, ly, model::region_name(reg), "start");
    lx += 100;
  }
  return g.done();
}

std::string steps_svg(const SweepCells& sweep, const Diagnosis& d) {
  const std::vector<double> strokes = sorted_unique(sweep, &CellKey::stroke_m);
  const double stroke = strokes.back();
  const std::vector<double> fr = sorted_unique(sweep, &CellKey::freq_hz);
  double lo = 0, hi = 0;
  for (std::size_t c = 0; c < sweep.cells.size(); ++c) {
    if (sweep.cells[c].key.stroke_m != stroke) continue;
    for (double v : {d.baseline.cells[c].measured_step_m, d.after.cells[c].model_step_m}) {
      lo = std::min(lo, v * 1e6);
      hi = std::max(hi, v * 1e6);
    }
  }
  if (hi - lo < 1e-3) hi = lo + 1;
  const double X0 = 70, Y0 = 50, W = 560, H = 380;
  Svg g(820, 490);
  g.text(20, 24, "Steady step against duty, stroke " + fmt("%.4g", stroke * 1e6) +
                      " um: measured (points, held-out mean) and the model after the diagnosis (lines)", "start", 13);
  auto px = [&](double duty) { return X0 + W * duty; };
  auto py = [&](double um) { return Y0 + H - H * (um - lo) / (hi - lo); };
  g.rect(X0, Y0, W, H, "none", "#444");
  for (int i = 0; i <= 10; ++i) {
    g.line(px(i / 10.0), Y0 + H, px(i / 10.0), Y0 + H + 4, "#444");
    g.text(px(i / 10.0), Y0 + H + 16, fmt("%.1f", i / 10.0), "middle", 10);
  }
  for (int i = 0; i <= 6; ++i) {
    const double v = lo + (hi - lo) * i / 6;
    g.line(X0 - 4, py(v), X0, py(v), "#444");
    g.text(X0 - 6, py(v) + 4, fmt("%.2f", v), "end", 10);
  }
  if (lo < 0 && hi > 0) g.line(X0, py(0), X0 + W, py(0), "#bbb");
  g.text(X0 + W / 2, Y0 + H + 34, "duty ratio");
  g.text(X0 - 48, Y0 + H / 2, "steady step (um per cycle)", "middle", 12, -90);
  static const char* colours[] = {"#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
                                  "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf"};
  for (std::size_t i = 0; i < fr.size(); ++i) {
    const char* col = colours[i % 10];
    std::vector<std::pair<double, double>> pts;  // duty, model step
    for (std::size_t c = 0; c < sweep.cells.size(); ++c) {
      const CellKey& k = sweep.cells[c].key;
      if (k.stroke_m != stroke || k.freq_hz != fr[i]) continue;
      g.s << "<circle cx=\"" << fmt("%.1f", px(k.duty)) << "\" cy=\"" << fmt("%.1f", py(d.baseline.cells[c].measured_step_m * 1e6))
          << "\" r=\"3\" fill=\"" << col << "\"/>\n";
      pts.push_back({k.duty, d.after.cells[c].model_step_m * 1e6});
    }
    std::sort(pts.begin(), pts.end());
    // lines within each direction (duty below / above 0.5)
    for (std::size_t k = 1; k < pts.size(); ++k)
      if ((pts[k - 1].first < 0.5) == (pts[k].first < 0.5))
        g.line(px(pts[k - 1].first), py(pts[k - 1].second), px(pts[k].first), py(pts[k].second), col, 1.5);
    g.rect(X0 + W + 20, Y0 + 10 + 20 * i, 12, 12, col);
    g.text(X0 + W + 38, Y0 + 21 + 20 * i, fmt("%g Hz", fr[i]), "start");
  }
  return g.done();
}

std::string gap_map_svg(const SweepCells& sweep, const GapEvaluation& eval, const std::string& title) {
  const std::vector<double> strokes = sorted_unique(sweep, &CellKey::stroke_m);
  const double pw = 300, ph = 280;
  Svg g(static_cast<int>(strokes.size() * (pw + 90) + 140), static_cast<int>(ph + 130));
  g.text(20, 22, title + " (held-out gap " + fmt("%.3g", eval.gap) + "; colour: cell residual, 1 = the noise)", "start", 14);
  auto colour = [&](double r) {
    // white at 0, yellow at the significance threshold, dark red at 100 and beyond (log scale)
    const double t = std::clamp(std::log10(1 + r) / 2.0, 0.0, 1.0);
    const int red = static_cast<int>(255 - 120 * std::max(0.0, t - 0.3) / 0.7);
    const int green = static_cast<int>(255 * (1 - t));
    const int blue = static_cast<int>(255 * std::max(0.0, 1 - 3 * t));
    char b[16];
    std::snprintf(b, sizeof b, "#%02x%02x%02x", red, green, blue);
    return std::string(b);
  };
  for (std::size_t r = 0; r < strokes.size(); ++r)
    panel(g, sweep, strokes[r], 70 + r * (pw + 90), 60, pw, ph, "stroke " + fmt("%.4g", strokes[r] * 1e6) + " um",
          [&](std::size_t c) { return colour(eval.cells[c].residual); });
  const double lx = 70 + strokes.size() * (pw + 90) - 20;
  for (int i = 0; i <= 4; ++i) {
    const double v = std::pow(10.0, i * 0.5) - 1;
    g.rect(lx, 70 + 24 * i, 16, 16, colour(v), "#888");
    g.text(lx + 22, 82 + 24 * i, fmt("%.3g", v), "start", 10);
  }
  return g.done();
}

std::string ranking_svg(const Diagnosis& d) {
  const double X0 = 170, W = 420, rowh = 26;
  Svg g(720, static_cast<int>(80 + rowh * (d.candidates.size() + d.not_identifiable.size())));
  g.text(20, 22, "Each effect added alone: shrink of the held-out gap (from " + fmt("%.3g", d.gap_before) + ")", "start", 14);
  auto px = [&](double s) { return X0 + W * std::clamp(s, 0.0, 1.0); };
  for (int i = 0; i <= 4; ++i) {
    g.line(px(i / 4.0), 40, px(i / 4.0), 50 + rowh * d.candidates.size(), "#ddd");
    g.text(px(i / 4.0), 38, fmt("%.0f %%", 25.0 * i), "middle", 10);
  }
  double y = 50;
  for (const CandidateResult& c : d.candidates) {
    const bool chosen = std::any_of(d.chosen.begin(), d.chosen.end(), [&](const model::EffectSpec& e) { return e.name == c.effect; });
    g.text(X0 - 8, y + 16, c.effect, "end");
    g.rect(X0, y + 4, std::max(0.0, px(c.shrink) - X0), rowh - 8, chosen ? "#2b8cbe" : (c.plausible ? "#a6bddb" : "#eeeeee"), "#666");
    g.text(px(std::max(0.0, c.shrink)) + 6, y + 16,
           fmt("%.1f %%", 100 * c.shrink) + " (gap " + fmt("%.3g", c.gap) + ")" + (c.plausible ? "" : " implausible") +
               (chosen ? " chosen" : ""), "start", 11);
    y += rowh;
  }
  for (const NotIdentifiable& n : d.not_identifiable) {
    g.text(X0 - 8, y + 16, n.effect, "end");
    g.text(X0, y + 16, "not identifiable: needs " + n.needs, "start", 11);
    y += rowh;
  }
  return g.done();
}

std::string write_report(const SweepCells& sweep, const Diagnosis& d, const std::string& summary, const std::string& dir) {
  std::filesystem::create_directories(dir);
  const std::filesystem::path p(dir);
  write_file_atomic((p / "regions.svg").string(), regions_svg(sweep, d));
  write_file_atomic((p / "steps.svg").string(), steps_svg(sweep, d));
  write_file_atomic((p / "gap_before.svg").string(), gap_map_svg(sweep, d.baseline, "Gap before: the impulse model"));
  write_file_atomic((p / "gap_after.svg").string(), gap_map_svg(sweep, d.after, "Gap after the diagnosis"));
  write_file_atomic((p / "ranking.svg").string(), ranking_svg(d));
  std::ostringstream h;
  h << "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>idm-gap: " << esc(sweep.name)
    << "</title></head>\n<body style=\"font-family:sans-serif;max-width:1200px\">\n<h1>Sim-to-real gap: "
    << esc(sweep.name) << "</h1>\n<pre>" << esc(summary) << "</pre>\n"
    << "<h2>Where: region maps</h2><img src=\"regions.svg\" alt=\"region maps\">\n"
    << "<h2>Step size against duty</h2><img src=\"steps.svg\" alt=\"steps\">\n"
    << "<h2>The gap, cell by cell</h2><img src=\"gap_before.svg\" alt=\"gap before\"><br><img src=\"gap_after.svg\" alt=\"gap after\">\n"
    << "<h2>Which effect</h2><img src=\"ranking.svg\" alt=\"ranking\">\n</body></html>\n";
  const std::string html = (p / "report.html").string();
  write_file_atomic(html, h.str());
  return html;
}

}  // namespace idm::analysis

// physketch study: the Pareto front of (time, error) and study.png, drawn with Cairo.
#include <cairo.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numeric>

#include "apps/physketch/study.h"
#include "core/error.h"

namespace physketch::app {

std::vector<bool> paretoFront(const std::vector<CostPoint>& points) {
  // Sweep in order of time (ties: error): a point is on the front when its error is below
  // that of every point strictly faster, and it is the least error among points as fast.
  std::vector<std::size_t> order;
  for (std::size_t i = 0; i < points.size(); ++i)
    if (!std::isnan(points[i].ms) && !std::isnan(points[i].error)) order.push_back(i);
  std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
    if (points[a].ms != points[b].ms) return points[a].ms < points[b].ms;
    if (points[a].error != points[b].error) return points[a].error < points[b].error;
    return a < b;
  });
  std::vector<bool> front(points.size(), false);
  double bestFaster = INFINITY;  // least error among points strictly faster than the current group
  for (std::size_t g = 0; g < order.size();) {
    std::size_t end = g;
    while (end < order.size() && points[order[end]].ms == points[order[g]].ms) ++end;
    const double groupMin = points[order[g]].error;  // sorted: the first is the group's least
    if (groupMin < bestFaster)
      for (std::size_t k = g; k < end && points[order[k]].error == groupMin; ++k) front[order[k]] = true;
    bestFaster = std::min(bestFaster, groupMin);
    g = end;
  }
  return front;
}

namespace {

// A log10 axis over [lo, hi] (positive), widened to whole decades when that is cheap and
// padded so markers do not sit on the frame.
struct LogAxis {
  double lo = 1, hi = 10;  // data units
  double a0 = 0, a1 = 1;   // pixels of lo and hi
  double px(double v) const { return a0 + (std::log10(v) - std::log10(lo)) / (std::log10(hi) - std::log10(lo)) * (a1 - a0); }
};

LogAxis makeAxis(double lo, double hi, double a0, double a1) {
  LogAxis ax;
  if (!(lo > 0)) lo = hi > 0 ? hi : 1.0;
  if (!(hi > 0)) hi = lo;
  double l = std::log10(lo), h = std::log10(hi);
  const double pad = std::max(0.08 * (h - l), 0.15);
  ax.lo = std::pow(10.0, l - pad);
  ax.hi = std::pow(10.0, h + pad);
  ax.a0 = a0;
  ax.a1 = a1;
  return ax;
}

std::string tickLabel(double v) {
  char buf[32];
  const int e = int(std::floor(std::log10(v) + 1e-9));
  const int m = int(std::round(v / std::pow(10.0, e)));
  if (e >= -2 && e <= 3) std::snprintf(buf, sizeof buf, "%g", m * std::pow(10.0, e));
  else if (m == 1) std::snprintf(buf, sizeof buf, "1e%d", e);
  else std::snprintf(buf, sizeof buf, "%de%d", m, e);
  return buf;
}

void text(cairo_t* cr, double x, double y, const std::string& s, double alignX, double alignY) {
  cairo_text_extents_t ext;
  cairo_text_extents(cr, s.c_str(), &ext);
  cairo_move_to(cr, x - alignX * ext.width - ext.x_bearing, y - alignY * ext.height - ext.y_bearing);
  cairo_show_text(cr, s.c_str());
}

// Ticks of a log axis: decades labelled, 2..9 unlabelled; `vertical` for the y axis.
void ticks(cairo_t* cr, const LogAxis& ax, bool vertical, double cross) {
  // Under two decades, 2 and 5 are labelled too, so every axis has a few numbers.
  // Over many decades only every `every`-th decade is labelled, and minor ticks are left out.
  const double decades = std::log10(ax.hi) - std::log10(ax.lo);
  const bool few = decades < 2.0;
  const int every = std::max(1, int(std::ceil(decades / 8.0)));
  for (int d = int(std::floor(std::log10(ax.lo))); d <= int(std::ceil(std::log10(ax.hi))); ++d)
    for (int m = 1; m <= 9; ++m) {
      const double v = m * std::pow(10.0, d);
      if (v < ax.lo || v > ax.hi) continue;
      if ((m > 1 && decades > 6.0) || (m == 1 && d % every != 0)) continue;
      const double p = ax.px(v), len = m == 1 ? 8 : 4;
      if (vertical) {
        cairo_move_to(cr, cross, p);
        cairo_line_to(cr, cross - len, p);
      } else {
        cairo_move_to(cr, p, cross);
        cairo_line_to(cr, p, cross + len);
      }
      cairo_stroke(cr);
      if (m == 1 || (few && (m == 2 || m == 5))) {
        if (vertical) text(cr, cross - 11, p, tickLabel(v), 1.0, 0.5);
        else text(cr, p, cross + 12, tickLabel(v), 0.5, 0.0);
        cairo_new_path(cr);
      }
      if (m == 1) {
        // Light grid line at each decade.
        cairo_save(cr);
        cairo_set_source_rgb(cr, 0.88, 0.88, 0.88);
        cairo_set_line_width(cr, 1);
        if (vertical) {
          cairo_move_to(cr, cross, p);
          cairo_line_to(cr, kPlotWidth - 40, p);
        } else {
          cairo_move_to(cr, p, cross);
          cairo_line_to(cr, p, 60);
        }
        cairo_stroke(cr);
        cairo_restore(cr);
      }
    }
}

cairo_status_t appendBytes(void* closure, const unsigned char* data, unsigned int length) {
  static_cast<std::string*>(closure)->append(reinterpret_cast<const char*>(data), length);
  return CAIRO_STATUS_SUCCESS;
}

}  // namespace

std::string studyPlotPng(const std::vector<PlotPoint>& points, const std::string& title, const std::string& errorLabel) {
  const double left = 110, right = kPlotWidth - 40, top = 70, bottom = kPlotHeight - 80;
  double msLo = INFINITY, msHi = -INFINITY, eLo = INFINITY, eHi = -INFINITY;
  for (const auto& p : points) {
    if (std::isnan(p.ms) || std::isnan(p.error) || !(p.ms > 0)) continue;
    msLo = std::min(msLo, p.ms);
    msHi = std::max(msHi, p.ms);
    if (p.error > 0) {
      eLo = std::min(eLo, p.error);
      eHi = std::max(eHi, p.error);
    }
  }
  if (!std::isfinite(msLo)) msLo = msHi = 1.0;
  if (!std::isfinite(eLo)) eLo = eHi = 1e-3;
  const LogAxis xAx = makeAxis(msLo, msHi, left, right);
  const LogAxis yAx = makeAxis(eLo, eHi, bottom, top);

  cairo_surface_t* surface = cairo_image_surface_create(CAIRO_FORMAT_RGB24, kPlotWidth, kPlotHeight);
  cairo_t* cr = cairo_create(surface);
  cairo_set_source_rgb(cr, 1, 1, 1);
  cairo_paint(cr);
  cairo_select_font_face(cr, "sans-serif", CAIRO_FONT_SLANT_NORMAL, CAIRO_FONT_WEIGHT_NORMAL);
  cairo_set_font_size(cr, 13);
  cairo_set_source_rgb(cr, 0, 0, 0);
  cairo_set_line_width(cr, 1.2);
  cairo_rectangle(cr, left, top, right - left, bottom - top);
  cairo_stroke(cr);
  ticks(cr, xAx, false, bottom);
  ticks(cr, yAx, true, left);
  text(cr, (left + right) / 2, kPlotHeight - 22, "wall time per frame (ms, log scale)", 0.5, 1.0);
  cairo_save(cr);
  cairo_translate(cr, 24, (top + bottom) / 2);
  cairo_rotate(cr, -M_PI / 2);
  text(cr, 0, 0, errorLabel + " (log scale)", 0.5, 0.5);
  cairo_restore(cr);
  cairo_set_font_size(cr, 15);
  text(cr, kPlotWidth / 2.0, 22, title, 0.5, 0.5);
  cairo_set_font_size(cr, 11);

  // The front, joined in order of time.
  std::vector<std::size_t> front;
  for (std::size_t i = 0; i < points.size(); ++i)
    if (points[i].front && !std::isnan(points[i].ms) && !std::isnan(points[i].error)) front.push_back(i);
  std::sort(front.begin(), front.end(), [&](std::size_t a, std::size_t b) {
    return points[a].ms != points[b].ms ? points[a].ms < points[b].ms : points[a].error > points[b].error;
  });
  const auto yOf = [&](double e) { return e > 0 ? yAx.px(e) : bottom - 6; };
  cairo_set_source_rgb(cr, 0.80, 0.15, 0.10);
  cairo_set_line_width(cr, 1.6);
  for (std::size_t k = 0; k < front.size(); ++k) {
    const double x = xAx.px(points[front[k]].ms), y = yOf(points[front[k]].error);
    if (k == 0) cairo_move_to(cr, x, y);
    else cairo_line_to(cr, x, y);
  }
  cairo_stroke(cr);

  bool anyZero = false;
  for (const auto& p : points) {
    if (std::isnan(p.ms) || std::isnan(p.error) || !(p.ms > 0)) continue;
    const double x = xAx.px(p.ms), y = yOf(p.error);
    cairo_new_path(cr);  // text leaves a current point: start the marker afresh
    if (p.front) cairo_set_source_rgb(cr, 0.80, 0.15, 0.10);
    else cairo_set_source_rgb(cr, 0.15, 0.30, 0.70);
    if (p.error > 0) {
      cairo_arc(cr, x, y, 5, 0, 2 * M_PI);
    } else {
      anyZero = true;  // the reference itself: on the bottom edge, an open triangle
      cairo_move_to(cr, x, y - 6);
      cairo_line_to(cr, x - 5, y + 3);
      cairo_line_to(cr, x + 5, y + 3);
      cairo_close_path(cr);
    }
    if (p.front && p.error > 0) cairo_fill(cr);
    else cairo_stroke(cr);
    if (p.front) {
      // Beside the marker, on its left where the right would leave the frame.
      cairo_text_extents_t ext;
      cairo_text_extents(cr, p.label.c_str(), &ext);
      cairo_set_source_rgb(cr, 0.25, 0.25, 0.25);
      if (x + 8 + ext.x_advance > kPlotWidth - 4) text(cr, x - 8, y - 4, p.label, 1.0, 1.0);
      else text(cr, x + 8, y - 4, p.label, 0.0, 1.0);
    }
  }

  // Legend, in one row between the title and the frame (it never hides a point).
  cairo_set_font_size(cr, 12);
  const double lx = left + 10, ly = top - 14;
  cairo_new_path(cr);
  cairo_set_source_rgb(cr, 0.15, 0.30, 0.70);
  cairo_arc(cr, lx, ly, 5, 0, 2 * M_PI);
  cairo_stroke(cr);
  cairo_set_source_rgb(cr, 0, 0, 0);
  text(cr, lx + 12, ly, "one setting", 0.0, 0.5);
  cairo_new_path(cr);
  cairo_set_source_rgb(cr, 0.80, 0.15, 0.10);
  cairo_arc(cr, lx + 130, ly, 5, 0, 2 * M_PI);
  cairo_fill(cr);
  cairo_set_source_rgb(cr, 0, 0, 0);
  text(cr, lx + 142, ly, "on the Pareto front (joined)", 0.0, 0.5);
  if (anyZero) text(cr, lx + 350, ly, "triangle on the bottom edge: error 0 (the reference itself)", 0.0, 0.5);

  std::string bytes;
  cairo_destroy(cr);
  cairo_surface_flush(surface);
  const cairo_status_t st = cairo_surface_write_to_png_stream(surface, appendBytes, &bytes);
  cairo_surface_destroy(surface);
  if (st != CAIRO_STATUS_SUCCESS) throw RuntimeError(std::string("study.png: ") + cairo_status_to_string(st));
  return bytes;
}

}  // namespace physketch::app

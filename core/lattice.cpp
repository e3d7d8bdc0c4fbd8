#include "core/lattice.h"

#include <algorithm>
#include <map>
#include <numeric>

namespace physketch {
namespace {

constexpr std::size_t kMaxDenseSlots = std::size_t(1) << 26;  // 256 MiB of int32 at most; the grid's box is 3.4 M

// Dense: one slot per cell of the bounding box (the first entry of `cells` there, or -1).
// Scanning the box in z, y, x order meets the components in the order of their first
// cells, which numbers them by their smallest cell in that order.
std::vector<std::int32_t> labelDense(const std::vector<Vec3i>& cells, const Vec3i& lo, const Vec3i& hi, int& count) {
  std::vector<std::int32_t> label(cells.size(), -1);
  const Vec3i n = hi - lo + Vec3i::Ones();
  auto slotOf = [&](const Vec3i& c) {
    return (std::size_t(c.z() - lo.z()) * std::size_t(n.y()) + std::size_t(c.y() - lo.y())) * std::size_t(n.x()) +
           std::size_t(c.x() - lo.x());
  };
  std::vector<std::int32_t> slot(std::size_t(n.x()) * std::size_t(n.y()) * std::size_t(n.z()), -1);
  for (std::size_t i = 0; i < cells.size(); ++i) {
    std::int32_t& s = slot[slotOf(cells[i])];
    if (s < 0) s = static_cast<std::int32_t>(i);
  }
  count = 0;
  std::vector<std::int32_t> stack;
  for (std::size_t s = 0; s < slot.size(); ++s) {
    if (slot[s] < 0 || label[static_cast<std::size_t>(slot[s])] >= 0) continue;
    label[static_cast<std::size_t>(slot[s])] = count;
    stack.push_back(slot[s]);
    while (!stack.empty()) {  // flood fill through the 26 neighbours
      const Vec3i c = cells[static_cast<std::size_t>(stack.back())];
      stack.pop_back();
      const Vec3i a = (c - Vec3i::Ones()).cwiseMax(lo), b = (c + Vec3i::Ones()).cwiseMin(hi);
      for (int z = a.z(); z <= b.z(); ++z)
        for (int y = a.y(); y <= b.y(); ++y)
          for (int x = a.x(); x <= b.x(); ++x) {
            const std::int32_t t = slot[slotOf(Vec3i(x, y, z))];
            if (t < 0 || label[static_cast<std::size_t>(t)] >= 0) continue;
            label[static_cast<std::size_t>(t)] = count;
            stack.push_back(t);
          }
    }
    ++count;
  }
  for (std::size_t i = 0; i < cells.size(); ++i)  // duplicates take the label of the slot's first entry
    label[i] = label[static_cast<std::size_t>(slot[slotOf(cells[i])])];
  return label;
}

// Sparse, for a bounding box too large to allocate: cells sorted in z, y, x order and
// neighbours found by binary search; the same labels as labelDense.
std::vector<std::int32_t> labelSorted(const std::vector<Vec3i>& cells, int& count) {
  const std::size_t n = cells.size();
  std::vector<std::int32_t> label(n, -1), order(n);
  std::iota(order.begin(), order.end(), 0);
  const auto less = [](const Vec3i& a, const Vec3i& b) {
    if (a.z() != b.z()) return a.z() < b.z();
    if (a.y() != b.y()) return a.y() < b.y();
    return a.x() < b.x();
  };
  std::stable_sort(order.begin(), order.end(), [&](std::int32_t a, std::int32_t b) { return less(cells[a], cells[b]); });
  count = 0;
  std::vector<std::int32_t> stack;
  for (std::int32_t s : order) {
    if (label[std::size_t(s)] >= 0) continue;
    label[std::size_t(s)] = count;
    stack.assign(1, s);
    while (!stack.empty()) {
      const Vec3i c0 = cells[static_cast<std::size_t>(stack.back())];
      stack.pop_back();
      for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            const Vec3i c = c0 + Vec3i(dx, dy, dz);
            auto it = std::lower_bound(order.begin(), order.end(), c,
                                       [&](std::int32_t a, const Vec3i& key) { return less(cells[a], key); });
            for (; it != order.end() && cells[std::size_t(*it)] == c; ++it)
              if (label[std::size_t(*it)] < 0) {
                label[std::size_t(*it)] = count;
                stack.push_back(*it);
              }
          }
    }
    ++count;
  }
  return label;
}

}  // namespace

std::vector<std::int32_t> componentLabels26(const std::vector<Vec3i>& cells, int* componentCount) {
  int count = 0;
  std::vector<std::int32_t> label;
  if (!cells.empty()) {
    Vec3i lo = cells.front(), hi = cells.front();
    for (const Vec3i& c : cells) lo = lo.cwiseMin(c), hi = hi.cwiseMax(c);
    const Eigen::Vector3d n = (hi - lo + Vec3i::Ones()).cast<double>();
    label = n.prod() <= double(kMaxDenseSlots) ? labelDense(cells, lo, hi, count) : labelSorted(cells, count);
  }
  if (componentCount) *componentCount = count;
  return label;
}

std::vector<std::vector<std::int32_t>> cutPieces(const std::vector<std::int32_t>& members, const std::vector<Vec3i>& cells,
                                                 const std::vector<std::int32_t>& design) {
  int count = 0;
  const std::vector<std::int32_t> label = componentLabels26(cells, &count);
  std::vector<std::vector<std::int32_t>> comp(static_cast<std::size_t>(count));
  for (std::size_t k = 0; k < members.size(); ++k) comp[std::size_t(label[k])].push_back(members[k]);
  // A component lies inside one design piece (a removal never connects anything).
  std::map<std::int32_t, int> fragmentsOf;
  for (const auto& c : comp) ++fragmentsOf[design[std::size_t(c.front())]];
  std::vector<std::int32_t> keep;
  std::vector<std::vector<std::int32_t>> out(1), fragments;
  for (auto& c : comp) {
    if (fragmentsOf[design[std::size_t(c.front())]] == 1) keep.insert(keep.end(), c.begin(), c.end());
    else fragments.push_back(std::move(c));
  }
  std::stable_sort(fragments.begin(), fragments.end(), [](const auto& a, const auto& c) {
    return a.size() != c.size() ? a.size() > c.size() : a.front() < c.front();
  });
  if (keep.empty() && !fragments.empty()) {
    keep = std::move(fragments.front());
    fragments.erase(fragments.begin());
  }
  std::sort(keep.begin(), keep.end());
  out[0] = std::move(keep);
  for (auto& f : fragments) out.push_back(std::move(f));
  return out;
}

}  // namespace physketch

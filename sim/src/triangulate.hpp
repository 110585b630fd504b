#pragma once
// Triangulation of a planar polygon with holes by ear clipping after bridging the holes into
// the outer boundary (sim-internal).
#include <Eigen/Core>
#include <array>
#include <vector>

namespace flashtwin::sim::detail {

using Vec2 = Eigen::Vector2d;

/// Triangles (indices into the concatenation outer ++ holes[0] ++ holes[1] ...), each
/// counter-clockwise. `outer` must be counter-clockwise, every hole clockwise, holes strictly
/// inside `outer` and disjoint. Returns an empty list when the input is degenerate.
std::vector<std::array<int, 3>> triangulate(const std::vector<Vec2>& outer,
                                            const std::vector<std::vector<Vec2>>& holes);

/// Signed area (positive for counter-clockwise).
double signed_area(const std::vector<Vec2>& loop);

}  // namespace flashtwin::sim::detail

#include "solvers/io/odometry_init.h"

#include <algorithm>
#include <climits>
#include <cmath>
#include <deque>
#include <string>
#include <unordered_set>

#include "solvers/geometry/se2.h"
#include "solvers/geometry/se3.h"

namespace loopd::io::detail {

namespace {

// What differs between 2D and 3D: reading a measurement, writing a pose or a landmark.
template <class Pose>
struct Geometry;

template <>
struct Geometry<SE2> {
  static SE2 measurement(const Edge& e) {
    return {e.measurement[0], e.measurement[1], e.measurement[2]};
  }
  static Vertex pose(std::int64_t id, const SE2& x) {
    Vertex v;
    v.type = VertexType::SE2;
    v.id = id;
    v.value = {x.x, x.y, x.theta};
    return v;
  }
  static Vertex landmark(const SE2& x, const Edge& e) {
    const double* z = e.measurement.data();
    const Vec2 local = e.type == EdgeType::BearingRange2
                           ? Vec2(z[1] * std::cos(z[0]), z[1] * std::sin(z[0]))
                           : Vec2(z[0], z[1]);
    const Vec2 p = x.transform(local);
    Vertex v;
    v.type = VertexType::Point2;
    v.id = e.to;
    v.value = {p.x(), p.y()};
    return v;
  }
};

template <>
struct Geometry<SE3> {
  static SE3 measurement(const Edge& e) {
    return SE3::fromTranslationQuaternion(e.measurement.data());
  }
  static Vertex pose(std::int64_t id, const SE3& x) {
    Vertex v;
    v.type = VertexType::SE3;
    v.id = id;
    x.toTranslationQuaternion(v.value.data());
    return v;
  }
  static Vertex landmark(const SE3& x, const Edge& e) {
    const Vec3 p = x.transform(Vec3(e.measurement[0], e.measurement[1], e.measurement[2]));
    Vertex v;
    v.type = VertexType::Point3;
    v.id = e.to;
    v.value = {p.x(), p.y(), p.z()};
    return v;
  }
};

/// Pose ids (sorted) and the first line that mentions each.
struct PoseIds {
  std::vector<std::int64_t> ids;
  std::vector<int> firstLine;

  explicit PoseIds(const std::vector<Edge>& edges) {
    for (const Edge& e : edges) {
      ids.push_back(e.from);
      if (isBetween(e.type)) ids.push_back(e.to);
    }
    std::sort(ids.begin(), ids.end());
    ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
    firstLine.assign(ids.size(), 0);
    for (const Edge& e : edges) {
      noteLine(e.from, e.line);
      if (isBetween(e.type)) noteLine(e.to, e.line);
    }
  }
  int indexOf(std::int64_t id) const {
    return static_cast<int>(std::lower_bound(ids.begin(), ids.end(), id) - ids.begin());
  }
  void noteLine(std::int64_t id, int line) {
    int& first = firstLine[indexOf(id)];
    if (first == 0) first = line;
  }
  bool contains(std::int64_t id) const { return std::binary_search(ids.begin(), ids.end(), id); }
};

// A between edge seen from one of its ends.
struct Arc {
  int from;      // pose index we leave
  int to;        // pose index we reach
  int edge;      // index into ds.edges
  bool forward;  // true when the edge reads from → to
};

template <class Pose>
std::vector<Pose> composePoses(const Dataset& ds, const PoseIds& poses) {
  const int n = static_cast<int>(poses.ids.size());
  // Adjacency in compressed rows: arcs of pose i are arcs[start[i] .. start[i+1]).
  std::vector<int> start(n + 1, 0);
  for (const Edge& e : ds.edges) {
    if (!isBetween(e.type)) continue;
    ++start[poses.indexOf(e.from) + 1];
    ++start[poses.indexOf(e.to) + 1];
  }
  for (int i = 0; i < n; ++i) start[i + 1] += start[i];
  std::vector<Arc> arcs(start[n]);
  std::vector<int> fill(start.begin(), start.end() - 1);
  for (int k = 0; k < static_cast<int>(ds.edges.size()); ++k) {
    const Edge& e = ds.edges[k];
    if (!isBetween(e.type)) continue;
    const int a = poses.indexOf(e.from), b = poses.indexOf(e.to);
    arcs[fill[a]++] = {a, b, k, true};
    arcs[fill[b]++] = {b, a, k, false};
  }

  // 0-1 breadth-first search: odometry arcs (between poses next to each other in id order)
  // cost 0, others 1, so the tree follows the odometry chain as far as it goes. A pose is placed
  // when it leaves the queue for the first time, by which point the pose it was reached from is
  // placed.
  struct Node {
    int cost = INT_MAX;
    Arc via{};
    bool placed = false;
  };
  std::vector<Node> nodes(n);
  std::vector<Pose> X(n);
  std::deque<int> queue;
  queue.push_back(0);
  nodes[0].cost = 0;
  while (!queue.empty()) {
    const int u = queue.front();
    queue.pop_front();
    if (nodes[u].placed) continue;
    nodes[u].placed = true;
    if (u != 0) {
      const Arc& a = nodes[u].via;
      const Pose z = Geometry<Pose>::measurement(ds.edges[a.edge]);
      X[u] = a.forward ? X[a.from] * z : X[a.from] * z.inverse();
    }
    for (int k = start[u]; k < start[u + 1]; ++k) {
      const Arc& a = arcs[k];
      Node& next = nodes[a.to];
      if (next.placed) continue;
      // Odometry joins neighbours in id order (Victoria Park skips the ids of landmarks).
      const int step = a.to == u + 1 || a.to == u - 1 ? 0 : 1;
      if (nodes[u].cost + step >= next.cost) continue;
      next.cost = nodes[u].cost + step;
      next.via = a;
      if (step == 0) {
        queue.push_front(a.to);
      } else {
        queue.push_back(a.to);
      }
    }
  }
  for (int i = 0; i < n; ++i) {
    if (!nodes[i].placed) {
      throw DatasetError(ds.path, poses.firstLine[i],
                         "pose " + std::to_string(poses.ids[i]) + " is not connected to pose " +
                             std::to_string(poses.ids[0]) +
                             " by between edges, so odometry cannot initialise it");
    }
  }
  return X;
}

template <class Pose>
void initialise(Dataset& ds, bool landmarkIdsShared) {
  const PoseIds poses(ds.edges);
  const std::vector<Pose> X = composePoses<Pose>(ds, poses);
  ds.poses.clear();
  ds.poses.reserve(X.size());
  for (std::size_t i = 0; i < X.size(); ++i) {
    ds.poses.push_back(Geometry<Pose>::pose(poses.ids[i], X[i]));
  }

  ds.landmarks.clear();
  std::unordered_set<std::int64_t> seen;
  for (const Edge& e : ds.edges) {
    if (isBetween(e.type)) continue;
    if (landmarkIdsShared && poses.contains(e.to)) {
      throw DatasetError(
          ds.path, e.line,
          "id " + std::to_string(e.to) + " is used both as a pose and as a landmark");
    }
    if (seen.insert(e.to).second) {
      ds.landmarks.push_back(Geometry<Pose>::landmark(X[poses.indexOf(e.from)], e));
    }
  }
  std::sort(ds.landmarks.begin(), ds.landmarks.end(),
            [](const Vertex& a, const Vertex& b) { return a.id < b.id; });
}

}  // namespace

void initialiseFromOdometry(Dataset& ds, bool landmarkIdsShared) {
  if (ds.is3d) {
    initialise<SE3>(ds, landmarkIdsShared);
  } else {
    initialise<SE2>(ds, landmarkIdsShared);
  }
}

}  // namespace loopd::io::detail

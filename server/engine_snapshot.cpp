// SAVE_SNAPSHOT: the graph and estimate as a g2o file loopd-solve reads (README, Snapshots):
// vertices in the frame the estimates are published in, ids in one block per robot and kind,
// the factors g2o can express as edges and the ambiguous groups as HYPOTHESES; priors,
// bearing-range sightings and cross-robot sightings kept back are left out and counted.
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstdio>
#include <map>

#include "server/anchored_sighting_factor.h"
#include "server/engine.h"
#include "solvers/factors/anchored_between_factor.h"
#include "solvers/factors/landmark_factors.h"
#include "solvers/io/estimate_writer.h"

namespace loopd::server {

namespace {

// g2o has one id space: each robot's poses, then each robot's landmarks, get a block of ids
// (robots in ascending order), the variable's index added to the block's first id. One
// robot without landmarks keeps its pose indices as ids.
class SnapshotIds {
 public:
  explicit SnapshotIds(const Values& est) {
    std::map<std::pair<bool, std::uint32_t>, std::uint64_t> top;  // (landmark?, robot) → max
    for (Key k : est.keys()) {
      if (keyKind(k) != KeyKind::Pose && keyKind(k) != KeyKind::Landmark) continue;
      auto& m = top[{keyKind(k) == KeyKind::Landmark, keyRobot(k)}];
      m = std::max(m, keyIndex(k));
    }
    std::uint64_t next = 0;
    for (const auto& [block, maxIndex] : top) {
      if (next > kMaxKeyIndex || maxIndex > kMaxKeyIndex - next)
        throw std::runtime_error(
            "the snapshot's ids would exceed " + std::to_string(kMaxKeyIndex) +
            " (what g2o readers keep); indices are too large to give each robot a block");
      first_[block] = next;
      next += maxIndex + 1;
    }
  }
  std::int64_t operator()(Key k) const {
    return static_cast<std::int64_t>(first_.at({keyKind(k) == KeyKind::Landmark, keyRobot(k)}) +
                                     keyIndex(k));
  }
  // "# robot 1 poses: id = 6 + index" per block, for the end of the file.
  std::string legend() const {
    std::string out;
    for (const auto& [block, first] : first_)
      out += "# robot " + std::to_string(block.second) + (block.first ? " landmarks" : " poses") +
             ": id = " + std::to_string(first) + " + index\n";
    return out;
  }

 private:
  std::map<std::pair<bool, std::uint32_t>, std::uint64_t> first_;
};

// A factor as a g2o edge between snapshot ids (measurements are relative, so they hold in any
// frame: an anchored inter-robot factor is the between of its two common-frame poses, an
// anchored sighting the sighting of its common-frame landmark). False
// for what g2o cannot express: priors, bearing-range.
bool toG2oEdge(const Factor& f, const SnapshotIds& id, io::Edge& e) {
  e = io::Edge();
  auto se2 = [&](Key a, Key b, const SE2& z, const Eigen::Matrix3d& info) {
    e.type = io::EdgeType::BetweenSE2;
    e.from = id(a);
    e.to = id(b);
    e.measurement[0] = z.x;
    e.measurement[1] = z.y;
    e.measurement[2] = z.theta;
    e.information.topLeftCorner<3, 3>() = info;
  };
  auto se3 = [&](Key a, Key b, const SE3& z, const Mat6& info) {
    e.type = io::EdgeType::BetweenSE3;
    e.from = id(a);
    e.to = id(b);
    z.toTranslationQuaternion(e.measurement.data());
    e.information = info;
  };
  auto point2 = [&](Key pose, Key landmark, const Vec2& z, const Eigen::Matrix2d& info) {
    e.type = io::EdgeType::PosePoint2;
    e.from = id(pose);
    e.to = id(landmark);
    e.measurement[0] = z.x();
    e.measurement[1] = z.y();
    e.information.topLeftCorner<2, 2>() = info;
  };
  auto point3 = [&](Key pose, Key landmark, const Vec3& z, const Mat3& info) {
    e.type = io::EdgeType::PosePoint3;
    e.from = id(pose);
    e.to = id(landmark);
    for (int i = 0; i < 3; ++i) e.measurement[static_cast<size_t>(i)] = z[i];
    e.information.topLeftCorner<3, 3>() = info;
  };
  if (const auto* b = dynamic_cast<const BetweenFactorSE2*>(&f)) {
    se2(f.key(0), f.key(1), b->measured(), b->information());
  } else if (const auto* b = dynamic_cast<const BetweenFactorSE3*>(&f)) {
    se3(f.key(0), f.key(1), b->measured(), b->information());
  } else if (const auto* a = dynamic_cast<const AnchoredBetweenFactorSE2*>(&f)) {
    se2(f.key(1), f.key(3), a->measured(), a->information());
  } else if (const auto* a = dynamic_cast<const AnchoredBetweenFactorSE3*>(&f)) {
    se3(f.key(1), f.key(3), a->measured(), a->information());
  } else if (const auto* p = dynamic_cast<const PosePointFactor2*>(&f)) {
    point2(f.key(0), f.key(1), p->measured(), p->information());
  } else if (const auto* p = dynamic_cast<const AnchoredPosePointFactor2*>(&f)) {
    point2(f.key(1), f.key(3), p->measured(), p->information());
  } else if (const auto* p = dynamic_cast<const PosePointFactor3*>(&f)) {
    point3(f.key(0), f.key(1), p->measured(), p->information());
  } else if (const auto* p = dynamic_cast<const AnchoredPosePointFactor3*>(&f)) {
    point3(f.key(1), f.key(3), p->measured(), p->information());
  } else {
    return false;
  }
  return true;
}

void appendText(const std::string& path, const std::string& text) {
  std::FILE* f = std::fopen(path.c_str(), "ab");
  const bool ok = f && std::fwrite(text.data(), 1, text.size(), f) == text.size();
  if ((f && std::fclose(f) != 0) || !ok) throw std::runtime_error("cannot append to " + path);
}

}  // namespace

void Engine::writeSnapshot(const std::string& path) const {
  const Values& est = backend_->estimate();
  const SnapshotIds ids(est);
  io::Dataset ds;
  ds.path = path;
  std::vector<Key> keys = est.keys();
  std::sort(keys.begin(), keys.end());
  auto vertexType = [](VarType t) {
    switch (t) {
      case VarType::SE3:
        return io::VertexType::SE3;
      case VarType::Point2:
        return io::VertexType::Point2;
      case VarType::Point3:
        return io::VertexType::Point3;
      default:
        return io::VertexType::SE2;
    }
  };
  for (Key k : keys) {
    const bool pose = keyKind(k) == KeyKind::Pose;
    std::vector<double> common;
    if ((!pose && keyKind(k) != KeyKind::Landmark) || !commonFramePose(k, common)) continue;
    io::Vertex v;
    v.id = ids(k);
    v.type = vertexType(est.type(est.slot(k)));
    std::copy(common.begin(), common.end(), v.value.begin());
    ds.is3d |= v.type == io::VertexType::SE3;
    (pose ? ds.poses : ds.landmarks).push_back(v);
  }
  std::map<std::string, int> skipped;  // the senders' factors g2o cannot express
  int gauge = 0;                       // the server's own priors (first poses, anchors)
  for (const auto& [fid, f] : live_) {
    io::Edge e;
    if (toG2oEdge(*f, ids, e)) {
      e.index = static_cast<int>(ds.edges.size());
      ds.edges.push_back(e);
    } else if (owners_.count(fid)) {
      ++skipped[f->typeName()];
    } else {
      ++gauge;
    }
  }
  int skippedGroups = 0;
  for (const auto& [gid, g] : groups_) {
    std::vector<io::Edge> alts;
    for (const auto& a : g.factor.alternatives) {
      io::Edge e;
      if (!toG2oEdge(*a, ids, e)) break;
      alts.push_back(e);
    }
    if (alts.size() != g.factor.alternatives.size()) {
      ++skippedGroups;
      continue;
    }
    io::HypothesisGroup h;
    h.firstEdge = static_cast<int>(ds.edges.size());
    h.count = static_cast<int>(alts.size());
    h.null = g.factor.nullHypothesis;
    ds.hypotheses.push_back(h);
    for (auto& e : alts) {
      e.index = static_cast<int>(ds.edges.size());
      ds.edges.push_back(e);
    }
  }
  std::string notes;
  for (const auto& [type, n] : skipped)
    notes += (notes.empty() ? "" : ", ") + std::to_string(n) + " " + type;
  if (skippedGroups > 0)
    notes += (notes.empty() ? "" : ", ") + std::to_string(skippedGroups) +
             " ambiguous groups with bearing-range alternatives";
  size_t keptBack = 0, keptClosures = 0;
  for (const auto& [pair, list] : pending_) keptBack += list.size();
  for (const auto& [pair, list] : pendingClosures_) keptClosures += list.size();
  std::string keptNote =
      keptBack == 0 ? ""
                    : std::to_string(keptBack) +
                          " cross-robot sightings, kept back until their robots share a frame";
  if (keptClosures > 0)
    keptNote += (keptNote.empty() ? "" : ", ") + std::to_string(keptClosures) +
                " inter-robot loop closures, kept back until enough agree";
  io::writeG2oGraph(path, ds);
  appendText(path, "# loopd snapshot: " + std::to_string(ds.poses.size()) + " poses, " +
                       std::to_string(ds.landmarks.size()) + " landmarks, " +
                       std::to_string(ds.edges.size()) + " edges (update " +
                       std::to_string(updateSeq_) + ")\n" + ids.legend() +
                       (notes.empty() ? "" : "# not written (no g2o form): " + notes + "\n") +
                       (keptNote.empty() ? "" : "# not written: " + keptNote + "\n"));
  if (!notes.empty())
    spdlog::warn("snapshot {}: not written (g2o has no form for them): {}", path, notes);
  if (!keptNote.empty()) spdlog::warn("snapshot {}: not written: {}", path, keptNote);
  spdlog::info("snapshot {}: {} poses, {} landmarks, {} edges ({} gauge priors left out)", path,
               ds.poses.size(), ds.landmarks.size(), ds.edges.size(), gauge);
}

}  // namespace loopd::server

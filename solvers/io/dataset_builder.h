#pragma once
// Collects what a reader parsed and applies the rules that do not depend on the format: unique
// vertex ids, no self-loops, no mixing of 2D and 3D, every edge end defined (in a file with
// vertices), at least one edge, and poses composed from odometry when the file has none.
// Internal to the readers.
#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

#include "solvers/io/dataset.h"
#include "solvers/io/line_scanner.h"

namespace loopd::io::detail {

class DatasetBuilder {
 public:
  /// `landmarkIdsShared`: g2o numbers poses and landmarks in one id space; Victoria Park
  /// numbers landmarks on their own.
  DatasetBuilder(const std::string& path, const char* format, bool landmarkIdsShared);

  /// Per-line checks; failures name the scanner's current line.
  void addVertex(const LineScanner& in, const Vertex& v);
  void addEdge(const LineScanner& in, Edge e);
  void addEquivalence(const LineScanner& in, std::int64_t a, std::int64_t b);
  /// `HYPOTHESES k [null]`: the next k lines must be edges of one type.
  void beginHypotheses(const LineScanner& in, int count, bool null);
  /// Fails if a HYPOTHESES group still waits for edges (call before a non-edge line).
  void expectNoOpenGroup(const LineScanner& in) const;

  /// Whole-file checks, then the dataset (poses composed from odometry if it had none).
  Dataset finish();

 private:
  void noteDimension(const LineScanner& in, bool is3d);
  /// Why `id` is not a defined vertex of the wanted kind; empty when it is.
  std::string vertexProblem(std::int64_t id, bool landmark) const;

  Dataset ds_;
  bool landmarkIdsShared_;
  int dimensionLine_ = 0;  // the first line that fixed 2D or 3D
  struct Seen {
    bool landmark;
    int line;
  };
  std::unordered_map<std::int64_t, Seen> vertexIds_;    // all vertices, or poses only
  std::unordered_map<std::int64_t, Seen> landmarkIds_;  // when landmarks have their own ids
  std::vector<int> equivalenceLines_;                   // parallel to ds_.equivalences
  int groupEdgesPending_ = 0;                           // edges the last HYPOTHESES still needs
};

}  // namespace loopd::io::detail

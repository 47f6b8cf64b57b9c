#pragma once
// Writing g2o files: an estimate as vertex lines (loopd-solve --out), or a whole graph
// (loopd-outliers). Numbers are written in the shortest form that reads back to the same
// double, so writeG2oGraph followed by readDataset gives back the same values bit for bit.
#include <string>

#include "solvers/io/dataset.h"

namespace loopd::io {

/// One g2o vertex line per pose, then per landmark, ids as in the dataset: VERTEX_SE2 id x y θ,
/// VERTEX_SE3:QUAT id x y z qx qy qz qw, VERTEX_XY id x y, VERTEX_TRACKXYZ id x y z.
/// Throws DatasetError(path, 0, reason) when the file cannot be written.
void writeG2oVertices(const std::string& path, const Dataset& estimate);

/// The vertex lines, then one line per edge in order: EDGE_SE2, EDGE_SE3:QUAT, EDGE_SE2_XY or
/// EDGE_SE3_TRACKXYZ with the information's upper triangle row by row (g2o's order); TORO
/// EQUIV pairs last, as EDGE_SE2 a b 0 0 0 with information kEquivalenceInformation·I (what
/// they are solved as; g2o has no EQUIV). Throws DatasetError for I/O failures,
/// for a bearing-range edge (no g2o tag), and when a landmark id equals a pose id (g2o has one
/// id space; Victoria Park has two).
void writeG2oGraph(const std::string& path, const Dataset& graph);

}  // namespace loopd::io

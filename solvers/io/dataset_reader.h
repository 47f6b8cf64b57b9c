#pragma once
// Reading pose-graph files: g2o (2D and 3D, with landmarks), TORO, and Victoria Park.
// Every malformed or inconsistent input throws DatasetError naming the file, the 1-based line
// and the reason; nothing is silently dropped. Files with edges only get poses composed from
// odometry (hadVertices = false), see solvers/io/odometry_init.h.
#include <string>
#include <string_view>

#include "solvers/io/dataset.h"

namespace loopd::io {

/// Reads a file, choosing the format from its first tag (g2o: VERTEX_SE2, EDGE_SE2,
/// VERTEX_SE3:QUAT, EDGE_SE3:QUAT, VERTEX_XY, EDGE_SE2_XY, VERTEX_TRACKXYZ, EDGE_SE3_TRACKXYZ,
/// FIX; TORO: VERTEX2, EDGE2, EQUIV; Victoria Park: ODOMETRY, LANDMARK). A file that cannot be
/// read gives line 0 and the OS reason.
Dataset readDataset(const std::string& path);

/// As readDataset, on text already in memory; `name` stands for the file in errors.
Dataset parseDataset(std::string_view text, const std::string& name);

/// The per-format parsers (a tag of another format is an unknown tag). Dataset::format is
/// "g2o", "toro" or "victoria".
Dataset parseG2o(std::string_view text, const std::string& name);
/// TORO EDGE2 stores the information as I11 I12 I22 I33 I13 I23.
Dataset parseToro(std::string_view text, const std::string& name);
/// ODOMETRY and LANDMARK carry covariances (upper triangle, row by row), stored inverted as
/// information. Landmark ids are their own namespace, separate from pose ids.
Dataset parseVictoria(std::string_view text, const std::string& name);

}  // namespace loopd::io

#pragma once
// The engine: the one thread that owns the Backend. It takes raw messages from the LCM thread
// (or a journal being resumed), decodes, de-duplicates, validates and stages batches, holds
// those that refer to poses not introduced yet, journals what it accepts, applies each round
// of staged batches as one Backend update (coalescing what arrived while it solved), runs
// commands, and publishes estimates, covariances, status and errors.
//
// Multi-robot (Kim et al. 2010): robot r's poses live in its own frame; its first pose gets a
// strong prior at its initial value (identity unless the front-end sent one). When an
// inter-robot between factor first joins r to s, anchor variables A = makeKey(robot, Anchor, 0)
// are created (the first robot of the group at identity with a strong prior; the joining one
// at A_s = A_r·x_r·Z·x_s⁻¹, so nothing jumps, with no prior: the inter-robot factor determines
// it, so the optimum equals the single-frame one) and the factor becomes an
// AnchoredBetweenFactor on (A_r, x_r, A_s, x_s). Joining two groups removes the joined group's
// root prior (its anchors then follow the factor). Removing inter-robot factors regroups the
// robots; a group left without a root prior gets one at its current value. Estimates are
// published as A_r ⊕ x_r.
//
// A pose of robot r may sight a landmark of robot s (cross-robot sighting): through the
// anchors it becomes an AnchoredPosePoint/BearingRange factor on (A_r, x_r, A_s, l_s). One
// sighting leaves the rotation between the frames free, so a pair's sightings are kept back
// (pending_, engine_sightings.cpp) until another factor joins the two frames or they name
// enough distinct landmarks fixed in s's frame to fix the transform (2 in 2D, 3 in 3D); the
// joining robot's anchor then starts at the least-squares alignment of those landmarks. A
// sighting of a landmark nobody has placed yet is kept back the same way (it does not hold its
// batch) and, once the frames are joined, places it in s's frame through the anchors. Such a
// landmark relates no frames until s ties it (ownerTies_): then the groups it joins merge, and
// removing the tie, like removing an inter-robot factor, regroups the robots. A landmark
// namespace (EngineOptions::landmarkNamespaces: a robot id with landmarks only) has no frame
// of its own: the first robot to sight one of its landmarks adopts it (adopted_), and from
// then on its landmarks are that robot's for every rule above (landmarkFrame).
//
// Under a solver that judges loop closures (Backend::judgesUncertain, or a closure's own kernel,
// sc or mm request), an inter-robot loop closure between robots whose frames are not joined yet
// is kept back as well (pendingClosures_, engine_closures.cpp): it alone would fix the
// transform between the frames, and a wrong one bends both maps from then on. A pair's kept-back
// closures join the frames once EngineOptions::joinAgreement of them agree on that transform
// (closure_agreement.h); all of them then go in, judged by the solver like any other. Another
// factor joining the frames first releases them the same way. A group of wrong closures agrees
// with itself, so such a join is checked again as the pair's closures grow (joinChecks_,
// engine_join_check.cpp): the robot it placed moves to a set of closures that outnumbers the
// joining ones' more than twice, and the solver is rebuilt there.
//
// An ambiguous alternative never creates an anchor (under "none" or another alternative it
// would be unconstrained, and each alternative implies another anchor value): an inter-robot
// alternative is accepted only between robots already joined by certain inter-robot factors
// (checkContext asks frameGroups) and is built as an AnchoredBetweenFactor like a certain
// one. Alternatives never join or split groups (regroup looks at certain factors only).
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <unordered_map>
#include <vector>

#include "loopd/command_t.hpp"
#include "loopd/factor_batch_t.hpp"
#include "robust/per_factor_backend.h"
#include "server/batch_validator.h"
#include "server/frame_groups.h"
#include "server/journal.h"
#include "server/publisher.h"
#include "server/session_table.h"
#include "server/wire_factors.h"
#include "solvers/backend/backend.h"

namespace loopd::server {

struct EngineOptions {
  std::string solver = "lm";
  int publishEvery = 50;     // full estimate snapshot every N updates (0 = never)
  double idleSeconds = 0.5;  // input pause before optimize() + converged publish
  // optimize() calls per input pause at most: one that spends its iteration budget still
  // descending (SolveSummary::budgetSpent) is resumed at the next idle(), publishing each time.
  int idleRounds = 10;
  int holdMaxBatches = 1000;         // held batches at most (oldest expire first)
  double holdSeconds = 30.0;         // a held batch expires after this long
  double priorInformation = 1e8;     // first-pose and root-anchor priors
  int maxMessageBytes = 256 * 1024;  // larger messages are refused before decoding
  double heartbeatSeconds = 1.0;
  int maxHypotheses = 10;  // mh: live hypotheses at most (BackendOptions::maxHypotheses)
  // Batches that queued while the engine solved are applied together, but one update takes
  // at most this many new poses of one robot (0: no bound): a long stretch of poses composed
  // from odometry, solved in one step, can land in another basin than one pose at a time does
  // (Victoria Park fed at full speed: rounds of thousands of poses ended at χ² 10⁵–10⁶).
  int posesPerUpdate = 100;
  // Robot ids that name landmark namespaces (--landmark-namespace): landmarks only, no poses;
  // the first robot to sight one of a namespace's landmarks holds them all in its frame.
  std::set<std::uint32_t> landmarkNamespaces;
  // Under a solver that judges loop closures, two robots' frames join once this many of their
  // inter-robot loop closures agree on the transform between them (PCM's pairwise test at
  // p = joinProbability); until then those closures are kept back. 1: the first one joins them,
  // right or wrong. Closures sent with robust "none" are trusted and join at once.
  int joinAgreement = 2;
  double joinProbability = 0.999;
};

struct Inbound {
  std::string channel;
  std::vector<std::uint8_t> bytes;
};

struct EngineCounters {
  std::int64_t accepted = 0, rejected = 0, duplicate = 0, expired = 0, held = 0, updates = 0,
               decodeFailed = 0, internalErrors = 0, journaled = 0;
  std::int64_t divergences = 0;  // solver steps that ranAway() (solver rebuilt, round refused)
  std::int64_t rejoins = 0;  // joins moved to a larger agreeing set of closures (solver rebuilt)
};

/// The engine treats an estimate as diverged (a solver that ran away) when a number in it is
/// NaN, ±inf or beyond 1e12 in magnitude: no map is a million kilometres across, a double
/// there no longer resolves 0.1 mm, and a runaway passes through such values finite (riSAM on
/// parking-garage with 100 random wrong closures: 1e3 to 1e188 m in 100 updates, never NaN).
constexpr double kRunawayMagnitude = 1e12;
bool ranAway(const Values& estimate);

class Engine : private GraphView {
 public:
  Engine(EngineOptions options, Publisher& publisher, Journal* journal);
  ~Engine() override;

  /// Queues a message (any thread). Messages over maxMessageBytes are refused here.
  void post(Inbound message);
  /// Messages waiting for the engine.
  int queueDepth() const;

  /// One round: everything queued now, then holds, the update, publishing (engine thread).
  /// Returns true if anything was processed.
  bool step();
  /// Housekeeping without input: expire holds, idle optimize, heartbeat.
  void idle();
  /// Nothing left for an idle optimize to do (the status's `converged`): no input since the
  /// last one, and that one did not stop on its budget with rounds left (idleRounds).
  bool settled() const { return !dirty_; }
  /// The engine thread's loop; returns once stop is set and the queue is drained.
  void run(const std::atomic<bool>& stop);

  /// Feeds a journal (resume). Its batches are not journaled again unless `rejournal`.
  std::int64_t replay(const std::string& path, bool rejournal, long* validBytes);

  // Introspection (engine thread, or after run() returned).
  const Backend& backend() const { return *backend_; }
  void setJournal(Journal* journal) { journal_ = journal; }
  EngineCounters counters() const;
  std::int64_t updateSeq() const { return updateSeq_; }
  /// A robot's pose (A ⊕ x) or landmark (A·p) in the common frame (its own while the robot is
  /// not joined), as published: x y θ, x y z qx qy qz qw, x y or x y z. False for anything else.
  bool commonFramePose(Key poseOrLandmark, std::vector<double>& out) const;
  bool robotJoined(std::uint32_t robot) const;

 private:
  struct RobotInfo {
    VarType poseType = VarType::SE2;
    Key firstPose = 0;
    std::int64_t latestIndex = -1;
    bool anchored = false;
    std::uint32_t parent = 0;      // union-find parent (itself when root)
    FactorId anchorPrior = 0;      // the anchor's prior factor (strong for a group root)
    std::int64_t placedFrom = -1;  // the robot whose frame a join placed this one's anchor from
  };
  struct Owner {
    std::string sender;
    std::int64_t id = 0;
    bool uncertain = false;
  };
  /// An ambiguous measurement in the graph: its sender's name for it and the backend's form
  /// (factor.id and every alternative's id are internal FactorIds).
  struct Group {
    std::string sender;
    std::int64_t id = 0;
    AmbiguousFactor factor;
  };
  /// A cross-robot sighting or inter-robot loop closure kept out of the solver until its robots'
  /// frames are joined.
  struct KeptBack {
    FactorPtr factor;  // single-frame form (keys x_r, l_s or x_s), its FactorId set
    Owner owner;
  };
  using RobotPair = std::pair<std::uint32_t, std::uint32_t>;  // lower robot first
  /// A pair's frames joined where some of its closures agreed (engine_join_check.cpp): a group
  /// of mutually consistent wrong closures agrees too, so the join is checked again as the
  /// pair's closures grow.
  struct JoinCheck {
    std::uint32_t placed = 0;         // the robot (or group root) the join placed, from the other
    std::set<FactorId> joiners;       // the agreeing closures the frames were joined at
    std::vector<FactorPtr> closures;  // the pair's judged closures since, single-frame forms
    size_t checkedAt = 0;             // closures.size() at the last check
    size_t pauseCheckedAt = 0;        // closures.size() at the last check at an input pause
    // The pair shares a frame through other robots' joins (no joiners): the placement holds
    // while the solver keeps most of the pair's largest agreeing set; `placed` is chosen when
    // it moves, as the robot of the two whose own join rests on fewer closures.
    bool throughOthers = false;
  };
  struct Decoded {
    std::shared_ptr<const loopd::factor_batch_t> batch;
    std::shared_ptr<const Inbound> raw;
    bool replayed = false;
  };
  struct Staged {
    Decoded d;
    BackendUpdate update;
    std::map<std::uint32_t, RobotInfo> robotsBefore;
    std::vector<std::pair<std::int64_t, FactorId>> addedIds;  // sender ids → FactorIds
    std::vector<std::pair<std::int64_t, FactorId>> removedIds;
    std::vector<Owner> owners;  // parallel to update.factors (sender id −1: server-owned)
    std::vector<Group> groups;  // parallel to update.ambiguous
    std::vector<FactorId> groupRemovals;  // internal ids of ambiguous groups removed
    std::map<RobotPair, std::vector<KeptBack>> pendingBefore;
    std::map<RobotPair, std::vector<KeptBack>> closuresBefore;
    std::vector<std::pair<RobotPair, JoinCheck>> joinsMade;  // committed into joinChecks_
    std::vector<FactorPtr> pairClosures;  // judged inter-robot closures in, single-frame forms
    std::map<std::uint32_t, std::uint32_t> adoptedBefore;
  };
  struct Held {
    Decoded d;
    std::chrono::steady_clock::time_point since;
    std::vector<Key> waiting;
  };
  enum class StageResult { Staged, Hold, Rejected };

  // GraphView
  std::optional<VarType> varType(Key k) const override;
  std::optional<VarType> robotPoseType(std::uint32_t robot) const override;
  bool idUsed(const std::string& sender, std::int64_t id) const override;
  bool idLive(const std::string& sender, std::int64_t id) const override;
  std::map<std::uint32_t, std::uint32_t> frameGroups(const loopd::factor_batch_t& b) const override;
  bool isLandmarkNamespace(std::uint32_t robot) const override {
    return opt_.landmarkNamespaces.count(robot) > 0;
  }
  std::uint32_t landmarkFrame(std::uint32_t robot) const override;
  /// The robot whose frame key k lives in: its own robot's, or for a landmark of an adopted
  /// landmark namespace, the adopting robot's.
  std::uint32_t frameOf(Key k) const {
    return keyKind(k) == KeyKind::Landmark ? landmarkFrame(keyRobot(k)) : keyRobot(k);
  }
  std::string solver() const override { return backend_->name(); }
  std::unique_ptr<PerFactorRobustBackend> makeSolver(const std::string& name) const;

  void handleFactors(std::shared_ptr<const Inbound> m, bool replayed);
  void handleCommand(const Inbound& m);
  StageResult stage(const Decoded& d, std::vector<Key>& waiting);
  void retryHolds();
  void expireHolds(bool all);
  void flush();
  void commit(Staged& s);
  /// Applies a round's update (plain factors, groups, removals of factors and of groups) to the
  /// backend: flattened for variants without hypotheses; on mh a group removal rebuilds the
  /// backend from the graph without it. Atomic: throws with the backend unchanged.
  std::vector<Key> applyUpdate(BackendUpdate update, const std::vector<FactorId>& groupRemovals);
  bool isGroupId(FactorId id) const;
  BackendOptions backendOptions() const;
  void undo(Staged& s);
  void reject(const loopd::factor_batch_t& b, const std::vector<Issue>& issues,
              const std::string& channel);

  // values
  const Values* holder(Key k) const;
  bool known(Key k) const { return holder(k) != nullptr; }
  std::uint32_t root(std::uint32_t r) const;
  /// Joins r's and s's frames (anchors created or groups merged) given M, the pose of s's frame
  /// in r's: from an inter-robot between factor M = x_r·Z·x_s⁻¹, from sightings an alignment.
  /// Returns the robot whose anchor the join placed (the newcomer, or the root of the group
  /// that follows), −1 when the frames were joined already.
  std::int64_t joinRobots(std::uint32_t r, std::uint32_t s, const SE2& m2, const SE3& m3,
                          Staged& st);
  /// Cross-robot sightings (engine_sightings.cpp): the batch's are kept back while their
  /// robots' frames are not joined; all of a pair's go in (anchored) once its frames are joined
  /// or its sightings fix the transform between them. The batch's guessed values are staged
  /// (holder() finds them) before it runs.
  void stageSightings(const std::vector<std::pair<FactorPtr, Owner>>& sightings, Staged& st);
  /// Unknown landmarks of robot s that only the batch's cross-robot sightings (from robots
  /// r ≠ s, at known or guessed poses) refer to: they do not hold the batch. The sightings are
  /// kept back as any other until r's and s's frames are joined, and then place the landmark.
  /// Keys of ambiguous alternatives are not among them (those must exist).
  std::set<Key> landmarksLeftToSightings(
      const loopd::factor_batch_t& b, const Values& knownVals, const Values& guess,
      const std::map<std::uint32_t, std::uint32_t>& adoptions) const;
  /// Initialises the landmark of sighting `f` (when it has no value yet) where the sighting puts
  /// it, in its owner's frame: A_s⁻¹·A_r·(x_r ⊕ z).
  void placeSightedLandmark(const Factor& f, Staged& st);
  /// A landmark namespace not adopted yet is adopted by the robot of the batch's first sighting
  /// of one of its landmarks (`adoptions`: those the batch makes, before it is staged).
  std::map<std::uint32_t, std::uint32_t> adoptionsOf(const loopd::factor_batch_t& b) const;
  /// A sighting whose landmark lives in another robot's frame than its pose (`adoptions`: the
  /// batch's own, from adoptionsOf).
  bool isCrossFrameSighting(const loopd::factor_t& f,
                            const std::map<std::uint32_t, std::uint32_t>& adoptions) const;
  /// Inter-robot loop closures under a solver that judges them (engine_closures.cpp): true if
  /// `f` (built, its robust request set) is to be kept back, its robots' frames not joined.
  bool keepsBack(const Factor& f) const;
  /// Whether an inter-robot closure joins its robots' frames as soon as it is staged (it is
  /// trusted, or the solver does not judge closures), whatever the frames are now.
  bool joinsAtOnce(const Factor& f) const;
  bool joinsAtOnce(const loopd::factor_t& wf) const;
  /// Both robots anchored in one group (sharing the common frame).
  bool shareFrame(std::uint32_t r, std::uint32_t s) const;
  /// Keeps the batch's such closures back; joins a pair's frames once enough of its closures
  /// agree, and releases (anchored) the closures of every pair whose frames are now joined.
  void stageInterRobotClosures(const std::vector<KeptBack>& closures, Staged& st);
  /// Releases the kept-back closures of every pair whose frames are joined now.
  void releaseJoinedClosures(Staged& st);
  /// What the agreement test of a pair's closures reads (closure_agreement.h): the two robots'
  /// odometry and poses, each in its frame, and the noise scale of their own closures.
  struct PairMaps {
    std::vector<FactorPtr> odometry;
    std::vector<FactorPtr> ownClosures;  // each within one robot; those the solver rejects out
    std::vector<FactorPtr> rejectedOwnClosures;  // those (committed ones)
    Values poses;
    double closureScale = 1.0;
  };
  /// The pair's maps with the staged rounds (and `building`) applied; `rejected`: the solver's
  /// rejected factors (rejectedFactors()), built once by the caller for all its pairs.
  PairMaps pairMaps(const RobotPair& pair, const Staged* building,
                    const std::set<FactorId>& rejected) const;
  /// The factors the solver rejects now, as a set.
  std::set<FactorId> rejectedFactors() const;
  /// `maps` with each robot's map relaxed on its own odometry and loop closures alone
  /// (own_map_relaxation.h): the rejected ones that fit the relaxed maps are taken back and
  /// the maps relaxed again with them. The closures' noise scale is read there.
  static PairMaps relaxedPairMaps(PairMaps maps);
  /// Indices into `closures` (single-frame inter-robot closures of the pair) of the largest
  /// set that agrees on the transform between the pair's frames, at `maps`.
  std::vector<size_t> agreeingPairClosures(const PairMaps& maps,
                                           const std::vector<FactorPtr>& closures) const;
  /// Checks each join made at agreeing closures once the pair's closures have grown by
  /// kJoinCheckGrowth (engine_join_check.cpp): when a larger set of them agrees on another
  /// transform than the one the frames were joined at, the robots the join placed are moved
  /// there and the solver is rebuilt from the graph at that start (`moved`: every variable).
  /// `atPause`: the input paused and the idle optimize settled; every pair whose closures
  /// changed since its last check at a pause is checked, whatever their growth.
  void checkJoins(std::vector<Key>& moved, bool atPause = false);
  /// One check of a join at one pair of maps: the largest agreeing set of the pair's closures,
  /// whether it holds the placement, and whether the frames move there.
  struct JoinVerdict {
    std::vector<FactorPtr> agree;
    size_t restLargest = 0;  // the largest set among the others (only when it may move)
    bool holds = false;
    bool moves = false;
  };
  /// `rejected`: the solver's rejected factors; `relaxed`: `maps` are relaxedPairMaps (the
  /// debug log says so).
  JoinVerdict judgeJoin(const RobotPair& pair, const JoinCheck& j, const PairMaps& maps,
                        const std::set<FactorId>& rejected, bool relaxed) const;
  /// The robot of `pair` whose own join rests on fewer closures (joins still checked; a root,
  /// a settled join or one made at a trusted factor is firm), −1 if both are firm.
  std::int64_t weakerPlacement(const RobotPair& pair) const;
  /// Moves the robot `j` placed (its anchor, so everything in its frame), and every robot a
  /// join placed from one that moves (RobotInfo::placedFrom), to where `agree` (closures of
  /// `pair`) puts it, rebuilds the solver there and records `agree` as the join's closures.
  /// False when a moving robot's anchor has a prior (it cannot follow).
  bool rejoin(const RobotPair& pair, JoinCheck& j, const std::vector<FactorPtr>& agree);
  /// The pose of s's frame in r's that between factor `z` (x_r → x_s) implies at the current
  /// (or staged) values: M = x_r·Z·x_s⁻¹.
  void frameOffset(const Factor& z, SE2& m2, SE3& m3) const;
  /// Removes a kept-back sighting or closure; false if `id` is not one.
  bool dropKeptBack(FactorId id);
  /// The inter-robot edges of the graph with the staged rounds (and `building`) applied.
  std::map<FactorId, InterEdge> currentInterEdges(const Staged* building) const;
  /// Which landmarks their owners tie to their own frames (ownerTiedLandmark), with the staged
  /// rounds (and `building`) applied: a landmark relates its owner's frame to a sighter's only
  /// when tied, or sighted from the owner's group.
  OwnerTies ownerTiesAt(const Staged* building) const;
  /// When the batch's factors on landmarks (an owner's tie, a sighting within a group) make
  /// landmarks join anchored groups (frame_groups.h), merges them: one root prior stays.
  void mergeGroupsJoinedByLandmarks(Staged& st);
  FactorPtr priorAt(Key k, const Values& from, int slot, double information);
  FactorId newFactorId() { return nextFactorId_++; }

  // publishing
  void afterUpdate(const std::vector<Key>& moved, double seconds, bool optimizeRun);
  /// `values`: the estimate to publish (default the backend's), `hypothesis`: its rank.
  void publishEstimates(const std::vector<Key>* moved, std::int64_t requestId, int onlyRobot,
                        const Values* values = nullptr, int hypothesis = 0);
  void publishLatestCovariances();
  void publishStatus(std::int64_t requestId, bool fullDecisions, int hypotheses = -1);
  std::vector<loopd::loop_decision_t> decisionList(bool full);
  Eigen::MatrixXd commonFrameCovariance(const std::vector<Key>& keys);
  /// A new `solver` fed the committed graph, started at `start` (default: the estimate).
  void rebuildBackend(const std::string& solver, const Values* start = nullptr);
  /// SAVE_SNAPSHOT (engine_snapshot.cpp): the graph and estimate as g2o at path. Throws
  /// std::exception saying why it could not be written.
  void writeSnapshot(const std::string& path) const;
  /// If `what` (an update, an idle optimize) left the backend's estimate ranAway(): logs it
  /// and puts in a new backend from the committed graph, started at lastGood (if given) and
  /// the sane rest, and returns true (engine_divergence.cpp). If that rebuild diverges too,
  /// it is logged and the backend stays as it is.
  bool recoverIfDiverged(const char* what, const Values* lastGood);
  /// After a pause's optimize(): whether the pause goes on (dirty_ stays set). Input waiting,
  /// an optimize() that spent its budget with rounds left (idleRounds), or, once settled, a
  /// join moved by checkJoins at the pause (a round too).
  bool pauseGoesOn();
  /// The rebuild itself; throws if the new backend diverges too.
  void recoverFromDivergence(const Values* lastGood);
  /// Gives a new backend the whole graph (mh: plain factors, optimize, then the groups).
  /// Throws if its estimate then ranAway().
  void feedRebuilt(Backend& next, BackendUpdate all);
  void resetAll();
  void regroup(std::vector<Key>& moved);
  void commandError(const loopd::command_t& c, std::int8_t code, const std::string& reason,
                    const std::string& channel);

  EngineOptions opt_;
  Publisher& pub_;
  Journal* journal_;
  FactorBatchValidator validator_;
  // The --solver variant inside the layer that applies each factor's own `robust` request.
  std::unique_ptr<PerFactorRobustBackend> backend_;

  mutable std::mutex qmu_;
  std::condition_variable qcv_;
  std::deque<std::shared_ptr<const Inbound>> queue_;

  SessionTable sessions_;
  std::map<std::uint32_t, RobotInfo> robots_;
  std::map<FactorId, FactorPtr> live_;
  std::unordered_map<FactorId, Owner> owners_;
  std::unordered_map<FactorId, double> lastDecisions_;
  std::map<FactorId, Group> groups_;  // ambiguous groups by internal id (= arrival order)
  std::unordered_map<FactorId, std::pair<int, double>> lastGroupDecisions_;
  FactorId nextFactorId_ = 1;
  std::int64_t loopClosures_ = 0;
  std::map<FactorId, InterEdge> interEdges_;  // anchored factors
  std::map<Key, int> ownerTies_;  // landmark → live factors of its owner's that tie it there
  std::map<std::uint32_t, std::uint32_t> adopted_;      // landmark namespace → its frame's robot
  std::map<RobotPair, std::vector<KeptBack>> pending_;  // sightings waiting for a join
  std::map<RobotPair, std::vector<KeptBack>> pendingClosures_;  // closures waiting for agreement
  std::map<RobotPair, JoinCheck> joinChecks_;  // joins made at agreeing closures, still checked
  std::set<RobotPair> settledJoins_;           // checks that ended with their placement holding
  bool regroupNeeded_ = false;

  std::vector<Staged> staged_;
  Values stagedValues_;
  std::deque<Held> holds_;

  std::int64_t updateSeq_ = 0;  // from the start time in µs (Engine::Engine)
  std::int64_t updatesSinceSnapshot_ = 0;
  double lastUpdateMs_ = 0.0, sumUpdateMs_ = 0.0;
  bool dirty_ = false;  // updated since the last optimize(), or that one is to be resumed
  int idleRound_ = 0;   // optimize() calls in this input pause (the one begun at pauseOf_)
  std::chrono::steady_clock::time_point pauseOf_;
  const std::atomic<bool>* stop_ = nullptr;  // run()'s stop flag, while it runs
  bool stopping() const { return stop_ && stop_->load(); }
  bool replaying_ = false;
  std::chrono::steady_clock::time_point lastInput_, lastStatus_;
  mutable std::mutex countersMu_;
  EngineCounters counters_;
};

}  // namespace loopd::server

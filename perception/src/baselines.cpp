// PCL baselines for the registration comparison: SAC-IA (FPFH) + NDT, NDT + ICP,
// ISS + 3D shape context + correspondence RANSAC + ICP, PCL's FPCS + ICP. PCL stays inside
// this file; the result type is the project's own.
//
// All lengths scale with the target's bounding-box diagonal d, so the same settings serve a
// 0.25 m bunny and a 0.3 m casting. Both clouds are thinned with pcl::VoxelGrid first:
//   coarse voxel  d/50   SAC-IA (normals, FPFH, samples, error), FPCS, the NDT source. SAC-IA
//                        scores every hypothesis on the whole cloud: at d/100 the Bunny keeps
//                        11.6k points and 1000 iterations take ~20 s; at d/50 it keeps ~3.2k
//                        (PCL's template-alignment tutorial uses about d/40).
//   feature voxel d/100  ISS keypoints and 3DSC descriptors (and their normals)
//   ICP voxel     d/200  ICP source; the ICP target is the whole target cloud
//   normals            radius 2.5 voxels, oriented away from the cloud's centroid
//   FPFH               radius 5 voxels
//   ISS                salient radius 6 voxels, non-maximum radius 4 voxels (PCL's example)
//   3DSC               support radius d/8, minimal radius 1/10 and density radius 1/5 of it
//   NDT                run on coordinates divided by d: cell size 1/12, line-search step 0.05
//   ICP                point-to-point, two rounds: correspondence distance d/20, then d/100
//   verdict            inlier distance d/100, confident when fitness >= 0.6, RMSE <= d/300
// Threads: normals, FPFH, ISS and FPCS use all hardware threads (OpenMP), as ours does.
#include "flashtwin/perception/baselines.hpp"

#include <pcl/common/transforms.h>
#include <pcl/features/3dsc.h>
#include <pcl/features/fpfh_omp.h>
#include <pcl/features/normal_3d_omp.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/keypoints/iss_3d.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/registration/correspondence_rejection_sample_consensus.h>
#include <pcl/registration/ia_fpcs.h>
#include <pcl/registration/ia_ransac.h>
#include <pcl/registration/icp.h>
#include <pcl/registration/ndt.h>
#include <pcl/search/kdtree.h>

#include <Eigen/Core>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <thread>
#include <vector>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/perception/preprocess.hpp"

#include <spdlog/spdlog.h>

namespace flashtwin::perception {

Baseline baseline_from_string(const std::string& s) {
  if (s == "sacia-ndt") return Baseline::kSacIaNdt;
  if (s == "sacia-ndt-icp") return Baseline::kSacIaNdtIcp;
  if (s == "ndt-icp") return Baseline::kNdtIcp;
  if (s == "iss-3dsc-icp") return Baseline::kIss3dscIcp;
  if (s == "fpcs-icp") return Baseline::kFpcsIcp;
  throw ArgumentError("baseline: expected one of sacia-ndt, sacia-ndt-icp, ndt-icp, iss-3dsc-icp, fpcs-icp, got \"" +
                      s + "\"");
}

std::string to_string(Baseline b) {
  switch (b) {
    case Baseline::kSacIaNdt: return "sacia-ndt";
    case Baseline::kSacIaNdtIcp: return "sacia-ndt-icp";
    case Baseline::kNdtIcp: return "ndt-icp";
    case Baseline::kIss3dscIcp: return "iss-3dsc-icp";
    case Baseline::kFpcsIcp: return "fpcs-icp";
  }
  return "unknown";
}

namespace {

using PointT = pcl::PointXYZ;
using Cloud = pcl::PointCloud<PointT>;
using Normals = pcl::PointCloud<pcl::Normal>;
using Tree = pcl::search::KdTree<PointT>;
using Mat4f = Eigen::Matrix4f;

// Settings, as fractions of the target diagonal (see the file comment).
constexpr double kCoarseVoxel = 1.0 / 50;
constexpr double kFeatureVoxel = 1.0 / 100;
constexpr double kIcpVoxel = 1.0 / 200;
constexpr double kNormalRadiusVoxels = 2.5;
constexpr double kFpfhRadiusVoxels = 5.0;
constexpr double kShapeContextRadius = 1.0 / 8;
constexpr double kNdtCell = 1.0 / 12;   // on coordinates divided by the diagonal
constexpr double kNdtStep = 0.05;       // same units
constexpr double kIcpCoarse = 1.0 / 20;
constexpr double kIcpFine = 1.0 / 100;
constexpr double kInlierDistance = 1.0 / 100;
constexpr double kMinFitness = 0.6;
constexpr double kMaxRmse = 1.0 / 300;

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

int thread_count() { return static_cast<int>(std::max(1u, std::thread::hardware_concurrency())); }

Cloud::Ptr to_pcl(const PointCloud& c) {
  Cloud::Ptr out(new Cloud);
  out->resize(c.size());
  for (std::size_t i = 0; i < c.size(); ++i) (*out)[i].getVector3fMap() = c.points[i];
  out->width = static_cast<std::uint32_t>(c.size());
  out->height = 1;
  out->is_dense = true;
  return out;
}

Cloud::Ptr voxel_grid(const Cloud::ConstPtr& in, double leaf) {
  Cloud::Ptr out(new Cloud);
  pcl::VoxelGrid<PointT> vg;
  vg.setInputCloud(in);
  const float l = static_cast<float>(leaf);
  vg.setLeafSize(l, l, l);
  vg.filter(*out);
  return out;
}

double bbox_diagonal(const PointCloud& c) {
  Eigen::AlignedBox3f box;
  for (const auto& p : c.points) box.extend(p);
  return static_cast<double>(box.diagonal().norm());
}

// Normals by radius PCA, flipped to point away from the cloud's centroid: the same rule for
// source and target whatever their pose, which FPFH needs (it is sign-sensitive). Points whose
// neighbourhood is too small for a normal are dropped from both outputs.
void normals_outward(Cloud::Ptr& cloud, Normals::Ptr& normals, double radius) {
  pcl::NormalEstimationOMP<PointT, pcl::Normal> ne;
  ne.setNumberOfThreads(static_cast<unsigned>(thread_count()));
  ne.setInputCloud(cloud);
  ne.setSearchMethod(Tree::Ptr(new Tree));
  ne.setRadiusSearch(radius);
  normals.reset(new Normals);
  ne.compute(*normals);
  Eigen::Vector3f c = Eigen::Vector3f::Zero();
  for (const auto& p : *cloud) c += p.getVector3fMap();
  c /= static_cast<float>(std::max<std::size_t>(1, cloud->size()));
  Cloud::Ptr kept(new Cloud);
  Normals::Ptr kept_n(new Normals);
  for (std::size_t i = 0; i < cloud->size(); ++i) {
    pcl::Normal n = (*normals)[i];
    if (!std::isfinite(n.normal_x) || !std::isfinite(n.normal_y) || !std::isfinite(n.normal_z))
      continue;
    if (n.getNormalVector3fMap().dot((*cloud)[i].getVector3fMap() - c) < 0)
      n.getNormalVector3fMap() *= -1.0f;
    kept->push_back((*cloud)[i]);
    kept_n->push_back(n);
  }
  cloud = kept;
  normals = kept_n;
}

Pose to_pose(const Mat4f& M) {
  Pose X = Pose::Identity();
  const Eigen::Matrix4d Md = M.cast<double>();
  X.linear() = nearest_rotation(Md.topLeftCorner<3, 3>());
  X.translation() = Md.topRightCorner<3, 1>();
  return X;
}

// Two rounds of point-to-point ICP (wide then narrow correspondence distance) of a fine voxel
// subset of the source against the full target (its k-d tree shared with the verdict).
Mat4f refine_icp(const Cloud::ConstPtr& source_fine, const Cloud::ConstPtr& target,
                 const Tree::Ptr& target_tree, const Mat4f& guess, double diag, bool& converged) {
  Mat4f T = guess;
  converged = true;
  for (const double dist : {kIcpCoarse, kIcpFine}) {
    pcl::IterativeClosestPoint<PointT, PointT> icp;
    icp.setInputSource(source_fine);
    icp.setInputTarget(target);
    icp.setSearchMethodTarget(target_tree, true);
    icp.setMaxCorrespondenceDistance(dist * diag);
    icp.setMaximumIterations(30);
    // Stop when a step moves less than 1e-6 d and turns less than float resolution, or the
    // mean squared error changes by less than 1e-6 relative.
    icp.setTransformationEpsilon(std::pow(1e-6 * diag, 2));
    icp.setTransformationRotationEpsilon(1.0 - 1e-9);
    icp.setEuclideanFitnessEpsilon(1e-6);
    Cloud aligned;
    icp.align(aligned, T);
    converged = converged && icp.hasConverged();
    if (icp.hasConverged()) T = icp.getFinalTransformation();
  }
  return T;
}

Cloud::Ptr scaled(const Cloud& c, float s) {
  Cloud::Ptr out(new Cloud(c));
  for (auto& p : *out) p.getVector3fMap() *= s;
  return out;
}

// NDT on coordinates divided by the diagonal: PCL's line search mixes metres and radians in
// one step vector, so a scale-free problem keeps rotations and translations balanced.
Mat4f refine_ndt(const Cloud& source, const Cloud& target, const Mat4f& guess, double diag,
                 bool& converged) {
  const float s = static_cast<float>(1.0 / diag);
  pcl::NormalDistributionsTransform<PointT, PointT> ndt;
  ndt.setResolution(static_cast<float>(kNdtCell));
  ndt.setStepSize(kNdtStep);
  ndt.setTransformationEpsilon(1e-10);  // squared step translation (units of the diagonal)
  ndt.setMaximumIterations(60);
  ndt.setInputSource(scaled(source, s));
  ndt.setInputTarget(scaled(target, s));
  Mat4f g = guess;
  g.topRightCorner<3, 1>() *= s;
  Cloud aligned;
  ndt.align(aligned, g);
  converged = ndt.hasConverged();
  Mat4f T = ndt.getFinalTransformation();
  T.topRightCorner<3, 1>() /= s;
  return T;
}

// 3D shape context comparison with Frome et al.'s azimuth search: PCL 1.13 draws the local x
// axis at random in the tangent plane, so two descriptors are compared under all 12 cyclic
// azimuth shifts and the smallest distance counts. Layout: index = azimuth·165 + (elev·15 + r).
pcl::Correspondences match_shape_contexts(const pcl::PointCloud<pcl::ShapeContext1980>& src,
                                          const pcl::PointCloud<pcl::ShapeContext1980>& tgt) {
  constexpr int kLen = 1980, kAzimuth = 12, kBlock = kLen / kAzimuth;
  using RowMat = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  const auto finite = [](const pcl::ShapeContext1980& d) {
    return std::all_of(d.descriptor, d.descriptor + kLen, [](float v) { return std::isfinite(v); });
  };
  std::vector<int> si, ti;
  for (std::size_t i = 0; i < src.size(); ++i)
    if (finite(src[i])) si.push_back(static_cast<int>(i));
  for (std::size_t i = 0; i < tgt.size(); ++i)
    if (finite(tgt[i])) ti.push_back(static_cast<int>(i));
  pcl::Correspondences out;
  if (si.empty() || ti.empty()) return out;
  RowMat T(ti.size(), kLen);
  for (std::size_t j = 0; j < ti.size(); ++j)
    T.row(static_cast<Eigen::Index>(j)) = Eigen::Map<const Eigen::RowVectorXf>(tgt[ti[j]].descriptor, kLen);
  const Eigen::VectorXf t2 = T.rowwise().squaredNorm();
  Eigen::MatrixXf best = Eigen::MatrixXf::Constant(static_cast<Eigen::Index>(si.size()),
                                                   static_cast<Eigen::Index>(ti.size()),
                                                   std::numeric_limits<float>::max());
  RowMat S(si.size(), kLen);
  for (int shift = 0; shift < kAzimuth; ++shift) {
    // Source descriptors rotated by `shift` azimuth bins.
    for (std::size_t i = 0; i < si.size(); ++i) {
      const float* d = src[si[i]].descriptor;
      for (int a = 0; a < kAzimuth; ++a)
        S.block(static_cast<Eigen::Index>(i), ((a + shift) % kAzimuth) * kBlock, 1, kBlock) =
            Eigen::Map<const Eigen::RowVectorXf>(d + a * kBlock, kBlock);
    }
    const Eigen::VectorXf s2 = S.rowwise().squaredNorm();
    const Eigen::MatrixXf d2 = (s2.replicate(1, T.rows()) + t2.transpose().replicate(S.rows(), 1) -
                                2.0f * (S * T.transpose()))
                                   .eval();
    best = best.cwiseMin(d2);
  }
  for (Eigen::Index i = 0; i < best.rows(); ++i) {
    Eigen::Index j = 0;
    const float d = best.row(i).minCoeff(&j);
    out.emplace_back(si[static_cast<std::size_t>(i)], ti[static_cast<std::size_t>(j)], d);
  }
  return out;
}

// ---------------------------------------------------------------- the four pipelines

struct Inputs {
  Cloud::Ptr source, target;  // full clouds
  Tree::Ptr target_tree;      // over the full target
  double diag = 0;
};

struct Outcome {
  Mat4f T = Mat4f::Identity();
  bool converged = false;
  std::string stage, failure;  // failure: why the pipeline produced no pose
};

// SAC-IA (FPFH) + NDT, and with `icp` a final ICP on the finer voxel grid as in ndt-icp.
Outcome run_sacia_ndt(const Inputs& in, bool icp = false) {
  Outcome o;
  o.stage = icp ? "sacia+ndt+icp" : "sacia+ndt";
  const auto t0 = Clock::now();
  const double voxel = kCoarseVoxel * in.diag;
  Cloud::Ptr src = voxel_grid(in.source, voxel), tgt = voxel_grid(in.target, voxel);
  Normals::Ptr sn, tn;
  normals_outward(src, sn, kNormalRadiusVoxels * voxel);
  normals_outward(tgt, tn, kNormalRadiusVoxels * voxel);
  if (src->size() < 3 || tgt->size() < 3) {
    o.failure = "too few points with normals after voxel filtering";
    return o;
  }
  using Fpfh = pcl::PointCloud<pcl::FPFHSignature33>;
  const auto fpfh = [&](const Cloud::Ptr& c, const Normals::Ptr& n) {
    pcl::FPFHEstimationOMP<PointT, pcl::Normal, pcl::FPFHSignature33> fe;
    fe.setNumberOfThreads(static_cast<unsigned>(thread_count()));
    fe.setInputCloud(c);
    fe.setInputNormals(n);
    fe.setSearchMethod(Tree::Ptr(new Tree));
    fe.setRadiusSearch(kFpfhRadiusVoxels * voxel);
    Fpfh::Ptr f(new Fpfh);
    fe.compute(*f);
    return f;
  };
  const Fpfh::Ptr sf = fpfh(src, sn), tf = fpfh(tgt, tn);
  const double t_features = seconds_since(t0);
  // SAC-IA as in PCL's template-alignment tutorial: 3 samples at least d/10 apart, one of the
  // 5 most similar target features at random, error truncated at 2 voxels (PCL compares
  // squared distances with this "distance", hence the square), 1000 iterations.
  pcl::SampleConsensusInitialAlignment<PointT, PointT, pcl::FPFHSignature33> sac;
  sac.setInputSource(src);
  sac.setSourceFeatures(sf);
  sac.setInputTarget(tgt);
  sac.setTargetFeatures(tf);
  sac.setMinSampleDistance(static_cast<float>(in.diag / 10));
  sac.setMaxCorrespondenceDistance(std::pow(2 * voxel, 2));
  sac.setMaximumIterations(1000);
  sac.setNumberOfSamples(3);
  sac.setCorrespondenceRandomness(5);
  Cloud aligned;
  sac.align(aligned);
  const double t_sac = seconds_since(t0);
  if (!sac.hasConverged()) {
    o.failure = "SAC-IA found no transformation";
    return o;
  }
  bool ndt_ok = false;
  o.T = refine_ndt(*src, *in.target, sac.getFinalTransformation(), in.diag, ndt_ok);
  spdlog::debug("sacia-ndt: {} / {} feature points; normals+FPFH {:.3f} s, SAC-IA {:.3f} s, NDT {:.3f} s",
                src->size(), tgt->size(), t_features, t_sac - t_features, seconds_since(t0) - t_sac);
  o.converged = ndt_ok;
  if (!ndt_ok) o.failure = "NDT did not converge";
  if (icp) {
    bool icp_ok = false;
    o.T = refine_icp(voxel_grid(in.source, kIcpVoxel * in.diag), in.target, in.target_tree, o.T,
                     in.diag, icp_ok);
    o.converged = o.converged && icp_ok;
    if (!icp_ok && o.failure.empty()) o.failure = "ICP did not converge";
  }
  return o;
}

Outcome run_ndt_icp(const Inputs& in) {
  Outcome o;
  o.stage = "ndt+icp";
  const auto t0 = Clock::now();
  const Cloud::Ptr src = voxel_grid(in.source, kCoarseVoxel * in.diag);
  bool ndt_ok = false;
  const Mat4f T0 = refine_ndt(*src, *in.target, Mat4f::Identity(), in.diag, ndt_ok);
  const double t_ndt = seconds_since(t0);
  bool icp_ok = false;
  o.T = refine_icp(voxel_grid(in.source, kIcpVoxel * in.diag), in.target, in.target_tree, T0,
                   in.diag, icp_ok);
  spdlog::debug("ndt-icp: {} NDT source points; NDT {:.3f} s, ICP {:.3f} s", src->size(), t_ndt,
                seconds_since(t0) - t_ndt);
  o.converged = ndt_ok && icp_ok;
  if (!ndt_ok) o.failure = "NDT did not converge";
  else if (!icp_ok) o.failure = "ICP did not converge";
  return o;
}

Outcome run_iss_3dsc_icp(const Inputs& in) {
  Outcome o;
  o.stage = "iss+3dsc+icp";
  const auto t0 = Clock::now();
  const double voxel = kFeatureVoxel * in.diag;
  Cloud::Ptr src = voxel_grid(in.source, voxel), tgt = voxel_grid(in.target, voxel);
  Normals::Ptr sn, tn;
  normals_outward(src, sn, kNormalRadiusVoxels * voxel);
  normals_outward(tgt, tn, kNormalRadiusVoxels * voxel);
  const auto keypoints = [&](const Cloud::Ptr& c) {
    pcl::ISSKeypoint3D<PointT, PointT> iss;
    iss.setSearchMethod(Tree::Ptr(new Tree));
    iss.setSalientRadius(6 * voxel);
    iss.setNonMaxRadius(4 * voxel);
    iss.setThreshold21(0.975);
    iss.setThreshold32(0.975);
    iss.setMinNeighbors(5);
    iss.setNumberOfThreads(static_cast<unsigned>(thread_count()));
    iss.setInputCloud(c);
    Cloud::Ptr k(new Cloud);
    iss.compute(*k);
    return k;
  };
  const Cloud::Ptr sk = keypoints(src), tk = keypoints(tgt);
  const double t_iss = seconds_since(t0);
  if (sk->size() < 3 || tk->size() < 3) {
    o.failure = "ISS found fewer than 3 keypoints (source " + std::to_string(sk->size()) +
                ", target " + std::to_string(tk->size()) + ")";
    return o;
  }
  using Desc = pcl::PointCloud<pcl::ShapeContext1980>;
  const double radius = kShapeContextRadius * in.diag;
  const auto describe = [&](const Cloud::Ptr& k, const Cloud::Ptr& surface, const Normals::Ptr& n) {
    pcl::ShapeContext3DEstimation<PointT, pcl::Normal, pcl::ShapeContext1980> sc;
    sc.setInputCloud(k);
    sc.setSearchSurface(surface);
    sc.setInputNormals(n);
    sc.setSearchMethod(Tree::Ptr(new Tree));
    sc.setRadiusSearch(radius);
    sc.setMinimalRadius(radius / 10);
    sc.setPointDensityRadius(radius / 5);
    Desc::Ptr d(new Desc);
    sc.compute(*d);
    return d;
  };
  const Desc::Ptr sd = describe(sk, src, sn), td = describe(tk, tgt, tn);
  const double t_3dsc = seconds_since(t0);
  const pcl::Correspondences matches = match_shape_contexts(*sd, *td);
  // Correspondence RANSAC: inliers within 2 feature voxels, then the best rigid transform.
  pcl::registration::CorrespondenceRejectorSampleConsensus<PointT> rej;
  rej.setInputSource(sk);
  rej.setInputTarget(tk);
  rej.setInlierThreshold(2 * voxel);
  rej.setMaximumIterations(20000);
  rej.setRefineModel(false);
  pcl::Correspondences inliers;
  rej.getRemainingCorrespondences(matches, inliers);
  const double t_match = seconds_since(t0);
  if (inliers.size() < 3) {
    o.failure = "correspondence RANSAC kept " + std::to_string(inliers.size()) + " of " +
                std::to_string(matches.size()) + " 3DSC matches";
    return o;
  }
  bool icp_ok = false;
  o.T = refine_icp(voxel_grid(in.source, kIcpVoxel * in.diag), in.target, in.target_tree,
                   rej.getBestTransformation(), in.diag, icp_ok);
  spdlog::debug("iss-3dsc-icp: {} / {} keypoints, {} of {} matches kept; normals+ISS {:.3f} s, 3DSC {:.3f} s, "
                "matching+RANSAC {:.3f} s, ICP {:.3f} s",
                sk->size(), tk->size(), inliers.size(), matches.size(), t_iss, t_3dsc - t_iss,
                t_match - t_3dsc, seconds_since(t0) - t_match);
  o.converged = icp_ok;
  if (!icp_ok) o.failure = "ICP did not converge";
  return o;
}

Outcome run_fpcs_icp(const Inputs& in) {
  Outcome o;
  o.stage = "fpcs+icp";
  const auto t0 = Clock::now();
  const double voxel = kCoarseVoxel * in.diag;
  const Cloud::Ptr src = voxel_grid(in.source, voxel), tgt = voxel_grid(in.target, voxel);
  // Overlap estimate for FPCS (base width and iteration count): the share of occupied target
  // voxels that the source occupies, a rotation-independent surface-area ratio. The early stop
  // is set apart from it: PCL scores the share of source samples near the target, which is
  // close to 1 at the right pose whatever the overlap, so stop only above 80 %.
  const double overlap =
      std::clamp(static_cast<double>(src->size()) / static_cast<double>(tgt->size()), 0.3, 0.9);
  // PCL 1.13's FPCS seeds rand() from the clock inside align(): runs are not repeatable.
  pcl::registration::FPCSInitialAlignment<PointT, PointT> fpcs;
  fpcs.setInputSource(src);
  fpcs.setInputTarget(tgt);
  fpcs.setApproxOverlap(static_cast<float>(overlap));
  fpcs.setDelta(1.0f, true);  // tolerance = mean target point spacing
  fpcs.setNumberOfSamples(200);
  fpcs.setNumberOfThreads(thread_count());
  fpcs.setScoreThreshold(0.2f);
  fpcs.setMaxComputationTime(10);  // [s] PCL's own cap
  Cloud aligned;
  fpcs.align(aligned);
  const bool fpcs_ok = fpcs.hasConverged();
  const double t_fpcs = seconds_since(t0);
  bool icp_ok = false;
  o.T = refine_icp(voxel_grid(in.source, kIcpVoxel * in.diag), in.target, in.target_tree,
                   fpcs.getFinalTransformation(), in.diag, icp_ok);
  spdlog::debug("fpcs-icp: {} / {} points, overlap {:.2f}, FPCS score {:.3f}; FPCS {:.3f} s, ICP {:.3f} s",
                src->size(), tgt->size(), overlap, fpcs.getFitnessScore(), t_fpcs,
                seconds_since(t0) - t_fpcs);
  o.converged = fpcs_ok && icp_ok;
  if (!fpcs_ok) o.failure = "FPCS did not reach its score threshold";
  else if (!icp_ok) o.failure = "ICP did not converge";
  return o;
}

}  // namespace

RegistrationResult register_baseline(Baseline method, const PointCloud& source,
                                     const PointCloud& target, std::uint64_t seed) {
  const auto t0 = std::chrono::steady_clock::now();
  RegistrationResult r;
  r.stage = to_string(method);
  const auto finish = [&]() -> RegistrationResult& {
    r.time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return r;
  };
  if (std::string why = validate_cloud(source); !why.empty()) {
    r.message = "source: " + why;
    return finish();
  }
  if (std::string why = validate_cloud(target); !why.empty()) {
    r.message = "target: " + why;
    return finish();
  }
  Inputs in;
  in.diag = bbox_diagonal(target);
  if (!(in.diag > 0)) {
    r.message = "target: expected a non-degenerate bounding box, got a diagonal of 0";
    return finish();
  }
  in.source = to_pcl(source);
  in.target = to_pcl(target);
  in.target_tree.reset(new Tree);
  in.target_tree->setInputCloud(in.target);
  // SAC-IA draws with rand(); FPCS reseeds it from the clock itself.
  std::srand(static_cast<unsigned>(seed ^ (seed >> 32)));

  Outcome o;
  switch (method) {
    case Baseline::kSacIaNdt: o = run_sacia_ndt(in); break;
    case Baseline::kSacIaNdtIcp: o = run_sacia_ndt(in, true); break;
    case Baseline::kNdtIcp: o = run_ndt_icp(in); break;
    case Baseline::kIss3dscIcp: o = run_iss_3dsc_icp(in); break;
    case Baseline::kFpcsIcp: o = run_fpcs_icp(in); break;
  }
  r.ran = true;
  r.stage = o.stage;
  if (!o.T.allFinite()) {
    o.T.setIdentity();
    o.converged = false;
    o.failure = "the pipeline returned a non-finite transformation";
  }
  r.T_target_source = to_pose(o.T);

  // Verdict as for the project's method: inliers of the whole source within d/100.
  const double inlier = kInlierDistance * in.diag;
  const Eigen::Matrix3f R = r.T_target_source.linear().cast<float>();
  const Eigen::Vector3f t = r.T_target_source.translation().cast<float>();
  std::size_t n_in = 0;
  double sum2 = 0;
  pcl::Indices idx(1);
  std::vector<float> d2(1);
  for (const auto& p : source.points) {
    PointT q;
    q.getVector3fMap() = R * p + t;
    if (in.target_tree->nearestKSearch(q, 1, idx, d2) < 1) continue;
    if (d2[0] <= inlier * inlier) {
      ++n_in;
      sum2 += d2[0];
    }
  }
  r.fitness = static_cast<double>(n_in) / static_cast<double>(source.size());
  r.rmse = n_in > 0 ? std::sqrt(sum2 / static_cast<double>(n_in)) : 0.0;
  const double max_rmse = kMaxRmse * in.diag;
  r.confident = o.failure.empty() && o.converged && r.fitness >= kMinFitness && r.rmse <= max_rmse;
  char buf[160];
  if (!o.failure.empty()) {
    r.message = o.failure;
  } else if (r.fitness < kMinFitness) {
    std::snprintf(buf, sizeof buf, "fitness %.3f below %.2f", r.fitness, kMinFitness);
    r.message = buf;
  } else if (r.rmse > max_rmse) {
    std::snprintf(buf, sizeof buf, "inlier RMSE %.3g mm above %.3g mm", r.rmse * 1e3, max_rmse * 1e3);
    r.message = buf;
  }
  return finish();
}

}  // namespace flashtwin::perception

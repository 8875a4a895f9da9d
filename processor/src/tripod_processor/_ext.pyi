"""tripod native core (private: use the tripod_processor Python API)"""

from collections.abc import Sequence
from typing import Annotated

import numpy
from numpy.typing import NDArray


OCTREE_CONTEXT_BITS: int = 22

OCTREE_MAX_DEPTH: int = 21

def voxelize_morton(points: Annotated[NDArray[numpy.float32], dict(shape=(None, 3), order='C', device='cpu', writable=False)], origin: Annotated[NDArray[numpy.float64], dict(shape=(3), order='C', device='cpu', writable=False)], voxel_size: float, depth: int, num_threads: int = 0) -> Annotated[NDArray[numpy.uint64], dict(shape=(None,))]:
    """
    Sorted unique Morton codes (uint64) of floor((points - origin) / voxel_size), clamped to [0, 2^depth). points: (N,3) float32 [m]; origin: (3,) float64 [m].
    """

def morton_to_points(codes: Annotated[NDArray[numpy.uint64], dict(shape=(None,), order='C', device='cpu', writable=False)], origin: Annotated[NDArray[numpy.float64], dict(shape=(3), order='C', device='cpu', writable=False)], voxel_size: float, num_threads: int = 0) -> Annotated[NDArray[numpy.float32], dict(shape=(None, 3))]:
    """Voxel centres (M,3) float32 [m] of Morton codes."""

def octree_contexts(codes: Annotated[NDArray[numpy.uint64], dict(shape=(None,), order='C', device='cpu', writable=False)], depth: int) -> tuple:
    """
    (contexts uint32, bits uint8) of every coded occupancy bit, in coding order.
    """

def octree_encode(codes: Annotated[NDArray[numpy.uint64], dict(shape=(None,), order='C', device='cpu', writable=False)], depth: int, p0_table: Annotated[NDArray[numpy.uint16], dict(shape=(None,), order='C', device='cpu', writable=False)], adapt_shift: int, adapt_prior: int = 0) -> bytes:
    """
    Range-code the octree of sorted unique Morton codes; returns the stream (bytes).
    """

def octree_decode(data: bytes, depth: int, n_voxels: int, p0_table: Annotated[NDArray[numpy.uint16], dict(shape=(None,), order='C', device='cpu', writable=False)], adapt_shift: int, adapt_prior: int = 0) -> Annotated[NDArray[numpy.uint64], dict(shape=(None,))]:
    """
    Decode an octree stream to sorted Morton codes (uint64); RuntimeError if corrupt.
    """

class _SphericalGrid:
    """The quantisation grid of a predictive stream"""

    def __init__(self) -> None: ...

    @property
    def origin(self) -> list[float]:
        """sensor origin [m]"""

    @origin.setter
    def origin(self, arg: Sequence[float], /) -> None: ...

    @property
    def range_step(self) -> float:
        """[m]"""

    @range_step.setter
    def range_step(self, arg: float, /) -> None: ...

    @property
    def az_count(self) -> int:
        """azimuth steps per turn"""

    @az_count.setter
    def az_count(self, arg: int, /) -> None: ...

    @property
    def el_step(self) -> float:
        """[rad] (used when el_table is empty)"""

    @el_step.setter
    def el_step(self, arg: float, /) -> None: ...

    @property
    def el_table(self) -> list[float]:
        """sorted elevations [rad], or empty"""

    @el_table.setter
    def el_table(self, arg: Sequence[float], /) -> None: ...

    @property
    def row_shift(self) -> int:
        """without a table: scan row of elevation index e is e >> row_shift"""

    @row_shift.setter
    def row_shift(self, arg: int, /) -> None: ...

    @property
    def z_table(self) -> list[float]:
        """per-laser heights [m] (size of el_table), or empty"""

    @z_table.setter
    def z_table(self, arg: Sequence[float], /) -> None: ...

    @property
    def az_predictor(self) -> int:
        """
        0: previous azimuth (predictive-sph1); 1: adaptive with the row predictor
        """

    @az_predictor.setter
    def az_predictor(self, arg: int, /) -> None: ...

class _PredictiveStats:
    """What predictive_encode measured"""

    @property
    def max_error_m(self) -> float:
        """largest distance of a decoded point from its input point [m]"""

    @property
    def checksum(self) -> int:
        """FNV-1a of the quantised points (for the decoder)"""

    @property
    def part_bits(self) -> tuple[float, float, float]:
        """estimated bits spent on (elevation, azimuth, range)"""

def spherical_coordinates(points: Annotated[NDArray[numpy.float32], dict(shape=(None, 3), order='C', device='cpu', writable=False)], origin: Annotated[NDArray[numpy.float64], dict(shape=(3), order='C', device='cpu', writable=False)], num_threads: int = 0) -> Annotated[NDArray[numpy.float64], dict(shape=(None, 3))]:
    """
    (N,3) float64 (range [m], azimuth [rad], elevation [rad]) of points about origin.
    """

def predictive_encode(points: Annotated[NDArray[numpy.float32], dict(shape=(None, 3), order='C', device='cpu', writable=False)], grid: _SphericalGrid, num_threads: int = 0) -> tuple[bytes, _PredictiveStats]:
    """
    Code points (N,3) float32 [m] in order on the grid; returns (stream, stats).
    """

def predictive_decode(data: bytes, n_points: int, grid: _SphericalGrid, checksum: int, num_threads: int = 0) -> Annotated[NDArray[numpy.float32], dict(shape=(None, 3))]:
    """
    Decode n_points (N,3) float32 [m] of a predictive stream; RuntimeError if corrupt.
    """

class _PcapLayout:
    """Layout of a classic pcap (its header)"""

    def __init__(self) -> None: ...

    @property
    def big_endian(self) -> bool:
        """record headers big-endian"""

    @big_endian.setter
    def big_endian(self, arg: bool, /) -> None: ...

    @property
    def nanosecond(self) -> bool:
        """fractions in ns, else us"""

    @nanosecond.setter
    def nanosecond(self, arg: bool, /) -> None: ...

    @property
    def linktype(self) -> int: ...

    @linktype.setter
    def linktype(self, arg: int, /) -> None: ...

class _PcapScan:
    """What one _scan_pcap_records call found"""

    @property
    def consumed(self) -> int:
        """bytes of the whole records scanned"""

    @property
    def records(self) -> int:
        """whole records scanned"""

    @property
    def oversize_bytes(self) -> int:
        """bytes claimed by the record that stopped the scan as corrupt, or 0"""

    @property
    def data(self) -> Annotated[NDArray[numpy.uint8], dict(shape=(None, None))]:
        """(n, data_size) uint8 payloads of plain Ethernet/IPv4/UDP records"""

    @property
    def data_t_ns(self) -> Annotated[NDArray[numpy.int64], dict(shape=(None,))]:
        """(n,) int64 capture time [ns]"""

    @property
    def data_port(self) -> Annotated[NDArray[numpy.uint16], dict(shape=(None,))]:
        """(n,) uint16 UDP destination port"""

    @property
    def data_record(self) -> Annotated[NDArray[numpy.int64], dict(shape=(None,))]:
        """(n,) int64 record index"""

    @property
    def other(self) -> Annotated[NDArray[numpy.int64], dict(shape=(None, None))]:
        """
        (k, 4) int64 [t_ns, payload offset, length, port] of other plain payloads
        """

    @property
    def slow(self) -> Annotated[NDArray[numpy.int64], dict(shape=(None, None))]:
        """
        (m, 4) int64 [t_ns, frame offset, length, record index] of records to parse in Python
        """

def _scan_pcap_records(buf: Annotated[NDArray[numpy.uint8], dict(shape=(None,), order='C', device='cpu', writable=False)], layout: _PcapLayout, data_size: int, max_record_bytes: int) -> _PcapScan:
    """
    Scan the whole classic-pcap records at the start of buf (uint8) (private: use tripod_processor.io.pcap.PcapReader).
    """

class _Vlp16DecoderConfig:
    """
    Filters of the batch decoder (velodyne-decoder's Config for the same purpose)
    """

    def __init__(self) -> None: ...

    @property
    def min_range_m(self) -> float:
        """returns nearer than this are dropped [m]"""

    @min_range_m.setter
    def min_range_m(self, arg: float, /) -> None: ...

    @property
    def max_range_m(self) -> float:
        """returns farther than this are dropped [m]"""

    @max_range_m.setter
    def max_range_m(self, arg: float, /) -> None: ...

    @property
    def min_angle_deg(self) -> float:
        """keep azimuths from here [deg] ..."""

    @min_angle_deg.setter
    def min_angle_deg(self, arg: float, /) -> None: ...

    @property
    def max_angle_deg(self) -> float:
        """... clockwise to here [deg]; across 0 when min > max"""

    @max_angle_deg.setter
    def max_angle_deg(self, arg: float, /) -> None: ...

class _DecodedChunk:
    """What one _Vlp16Decoder.decode call gave"""

    @property
    def points(self) -> Annotated[NDArray[numpy.uint8], dict(shape=(None, None))]:
        """(M, 20) uint8 = POINT_DTYPE records"""

    @property
    def time_s(self) -> Annotated[NDArray[numpy.float32], dict(shape=(None,))]:
        """(M,) float32 velodyne-decoder time since packet 0 [s], or empty"""

    @property
    def block_first_point(self) -> Annotated[NDArray[numpy.int64], dict(shape=(None,))]:
        """(N*12+1,) int64 first point of each flat block"""

    @property
    def status(self) -> Annotated[NDArray[numpy.uint8], dict(shape=(None,))]:
        """
        (N,) uint8 per packet: 0 ok, 1 bad block header (the blocks before it kept)
        """

    @property
    def time_offset_clipped(self) -> bool: ...

    @property
    def return_type_after(self) -> int:
        """pass it as return_type_before of the next chunk"""

class _Vlp16Decoder:
    """
    Batch VLP-16 / Puck Hi-Res decoder equal to velodyne-decoder 3.1 (private: use tripod_processor.decode)
    """

    def __init__(self, corrections: Annotated[NDArray[numpy.float64], dict(shape=(16, 12), order='C', device='cpu', writable=False)], distance_resolution_m: float, rings: Annotated[NDArray[numpy.uint8], dict(shape=(16), order='C', device='cpu', writable=False)], config: _Vlp16DecoderConfig) -> None:
        """
        corrections: (16, 12) float64, per laser in firing order: rot_correction [rad], vert_correction [rad], dist_correction [m], two_pt_correction_available (0/1), dist_correction_x [m], dist_correction_y [m], vert_offset_correction [m], horiz_offset_correction [m], max_intensity, min_intensity, focal_distance, focal_slope. rings: (16,) uint8 rank of each laser by elevation.
        """

    def decode(self, packets: Annotated[NDArray[numpy.uint8], dict(shape=(None, 1206), order='C', device='cpu', writable=False)], stamps_ns: Annotated[NDArray[numpy.int64], dict(shape=(None,), order='C', device='cpu', writable=False)], seg_first_block: Annotated[NDArray[numpy.int64], dict(shape=(None,), order='C', device='cpu', writable=False)] | None = None, seg_ref_ns: Annotated[NDArray[numpy.int64], dict(shape=(None,), order='C', device='cpu', writable=False)] | None = None, with_time_s: bool = False, num_threads: int = 0, return_type_before: int = 63) -> _DecodedChunk:
        """
        Decode (N, 1206) uint8 packets stamped (N,) int64 [ns]; segments (frames) of the chunk: their first flat block (packet * 12 + block) and reference time [ns].
        """

def voxel_local_shape(points: Annotated[NDArray[numpy.float32], dict(shape=(None, 3), order='C', device='cpu', writable=False)], voxel_size: float, radius_voxels: int = 1, num_threads: int = 0) -> Annotated[NDArray[numpy.float32], dict(shape=(None, None))]:
    """
    Per-point normal, covariance eigenvalues and neighbour count from voxel moments.
    points: (N,3) float32 [m]; returns (N,7) float32: nx ny nz l0 l1 l2 count.
    """

class _VoxelAssignment:
    """What voxel_assign found"""

    @property
    def centroids(self) -> Annotated[NDArray[numpy.float32], dict(shape=(None, 3))]:
        """(M, 3) float32 voxel centroids [m]"""

    @property
    def point_voxel(self) -> Annotated[NDArray[numpy.int32], dict(shape=(None,))]:
        """(N,) int32 voxel of each point (-1 for non-finite points)"""

    @property
    def counts(self) -> Annotated[NDArray[numpy.int32], dict(shape=(None,))]:
        """(M,) int32 points per voxel"""

def voxel_assign(points: Annotated[NDArray[numpy.float32], dict(shape=(None, 3), order='C', device='cpu', writable=False)], voxel_size: float, num_threads: int = 0) -> _VoxelAssignment:
    """Group points (N,3) float32 [m] by voxel."""

class _ColumnContextOptions:
    """Settings of column_context"""

    def __init__(self) -> None: ...

    @property
    def cell_size(self) -> float:
        """side of a grid cell [m]"""

    @cell_size.setter
    def cell_size(self, arg: float, /) -> None: ...

    @property
    def z_low(self) -> float:
        """occupancy band: points between z_low and z_high [m]"""

    @z_low.setter
    def z_low(self, arg: float, /) -> None: ...

    @property
    def z_high(self) -> float: ...

    @z_high.setter
    def z_high(self, arg: float, /) -> None: ...

    @property
    def num_directions(self) -> int:
        """horizontal rays per occupied cell"""

    @num_directions.setter
    def num_directions(self, arg: int, /) -> None: ...

    @property
    def skip(self) -> float:
        """rays start this far from their cell [m]"""

    @skip.setter
    def skip(self, arg: float, /) -> None: ...

    @property
    def max_range(self) -> float:
        """a ray that leaves this far without a hit is open [m]"""

    @max_range.setter
    def max_range(self, arg: float, /) -> None: ...

    @property
    def num_threads(self) -> int:
        """0 = all cores"""

    @num_threads.setter
    def num_threads(self, arg: int, /) -> None: ...

def column_context(points: Annotated[NDArray[numpy.float32], dict(shape=(None, 3), order='C', device='cpu', writable=False)], upright: Annotated[NDArray[numpy.uint8], dict(shape=(None,), order='C', device='cpu', writable=False)], options: _ColumnContextOptions) -> Annotated[NDArray[numpy.float32], dict(shape=(None, None))]:
    """
    Horizontal context per point of a z-up scan. points: (N,3) float32 [m]; upright: (N,)
    uint8 flags of the points that count for column heights; returns (N,5) float32: open
    fraction, mean free distance [m], column z-min [m], column z-max [m], log1p(count).
    """

def nearest_within(ref: Annotated[NDArray[numpy.float64], dict(shape=(None, 3), order='C', device='cpu', writable=False)], query: Annotated[NDArray[numpy.float64], dict(shape=(None, 3), order='C', device='cpu', writable=False)], radius: float) -> tuple[Annotated[NDArray[numpy.float64], dict(shape=(None,))], Annotated[NDArray[numpy.int64], dict(shape=(None,))], int]:
    """
    (dist, index, ties): per query row the nearest ref row strictly closer than radius, as scipy's cKDTree.query(k=1, distance_upper_bound=radius) gives them (inf / len(ref) where none is); ties counts the queries whose nearest distance two refs share (there the lowest index, where cKDTree keeps the one its traversal meets first). Private: see tripod_processor.reconstruction.stations.
    """

def place_points(points: Annotated[NDArray[numpy.float32], dict(shape=(None, 3), order='C', device='cpu', writable=False)], t_ns: Annotated[NDArray[numpy.int64], dict(shape=(None,), order='C', writable=False)], imu_t_ns: Annotated[NDArray[numpy.int64], dict(shape=(None,), order='C', writable=False)], imu_q_wxyz: Annotated[NDArray[numpy.float64], dict(shape=(None, 4), order='C', writable=False)], R_imu_lidar: Annotated[NDArray[numpy.float64], dict(shape=(3, 3), order='C', writable=False)], lever_arm: Annotated[NDArray[numpy.float64], dict(shape=(3), order='C', writable=False)], anchor_ns: int, num_threads: int = 0) -> Annotated[NDArray[numpy.float32], dict(shape=(None, 3))]:
    """
    De-skew points into the lidar frame at anchor_ns (private: see tripod_processor.reconstruction.placement.place_points).
    """

class _PoseGraphOptions:
    """Settings of optimize_pose_graph"""

    def __init__(self) -> None: ...

    @property
    def loss(self) -> str:
        """none, huber, cauchy or soft_l1 (loop edges)"""

    @loss.setter
    def loss(self, arg: str, /) -> None: ...

    @property
    def loss_scale(self) -> float:
        """robust kernel scale [sigmas]"""

    @loss_scale.setter
    def loss_scale(self, arg: float, /) -> None: ...

    @property
    def robust_odometry(self) -> bool:
        """odometry edges robust too"""

    @robust_odometry.setter
    def robust_odometry(self, arg: bool, /) -> None: ...

    @property
    def max_iterations(self) -> int: ...

    @max_iterations.setter
    def max_iterations(self, arg: int, /) -> None: ...

    @property
    def num_threads(self) -> int:
        """0 = all cores"""

    @num_threads.setter
    def num_threads(self, arg: int, /) -> None: ...

    @property
    def fixed_node(self) -> int:
        """node held constant (-1: none)"""

    @fixed_node.setter
    def fixed_node(self, arg: int, /) -> None: ...

    @property
    def outlier_chi2(self) -> float:
        """reject loop edges above this chi2"""

    @outlier_chi2.setter
    def outlier_chi2(self, arg: float, /) -> None: ...

    @property
    def max_rejection_rounds(self) -> int: ...

    @max_rejection_rounds.setter
    def max_rejection_rounds(self, arg: int, /) -> None: ...

    @property
    def reject_odometry(self) -> bool:
        """odometry edges rejectable when the graph stays connected"""

    @reject_odometry.setter
    def reject_odometry(self, arg: bool, /) -> None: ...

class _PoseGraphResult:
    """What optimize_pose_graph found"""

    @property
    def T_world_node(self) -> Annotated[NDArray[numpy.float64], dict(shape=(None, 4, 4))]:
        """(n, 4, 4) float64 optimised poses"""

    @property
    def edge_chi2(self) -> Annotated[NDArray[numpy.float64], dict(shape=(None,))]:
        """(m,) float64 whitened squared error of each edge"""

    @property
    def edge_inlier(self) -> Annotated[NDArray[numpy.uint8], dict(shape=(None,))]:
        """(m,) uint8: 0 for rejected edges"""

    @property
    def initial_cost(self) -> float: ...

    @property
    def final_cost(self) -> float: ...

    @property
    def iterations(self) -> int:
        """summed over all solves"""

    @property
    def rejected(self) -> int:
        """rejected edges"""

    @property
    def converged(self) -> bool: ...

    @property
    def message(self) -> str:
        """Ceres' termination message of the last solve"""

def optimize_pose_graph(T_world_node: Annotated[NDArray[numpy.float64], dict(shape=(None, 4, 4), order='C', device='cpu', writable=False)], edge_nodes: Annotated[NDArray[numpy.int64], dict(shape=(None, 2), order='C', device='cpu', writable=False)], T_from_to: Annotated[NDArray[numpy.float64], dict(shape=(None, 4, 4), order='C', device='cpu', writable=False)], information: Annotated[NDArray[numpy.float64], dict(shape=(None, 6, 6), order='C', device='cpu', writable=False)], is_loop: Annotated[NDArray[numpy.bool_], dict(shape=(None,), order='C', device='cpu', writable=False)], gravity_nodes: Annotated[NDArray[numpy.int64], dict(shape=(None,), order='C', device='cpu', writable=False)], gravity_up: Annotated[NDArray[numpy.float64], dict(shape=(None, 3), order='C', device='cpu', writable=False)], gravity_sigma: Annotated[NDArray[numpy.float64], dict(shape=(None,), order='C', device='cpu', writable=False)], options: _PoseGraphOptions) -> _PoseGraphResult:
    """
    Pose-graph optimisation in Ceres (private: use tripod_processor.registration.pose_graph).
    """

class _Normals:
    """What estimate_normals found"""

    @property
    def normals(self) -> Annotated[NDArray[numpy.float64], dict(shape=(None, 3))]:
        """(N, 3) float64 unit normals towards the viewpoint"""

    @property
    def covariances(self) -> Annotated[NDArray[numpy.float64], dict(shape=(None, 9))]:
        """(N, 9) float64 row-major 3x3 [m^2]"""

    @property
    def curvature(self) -> Annotated[NDArray[numpy.float64], dict(shape=(None,))]:
        """(N,) float64 lambda_min / sum (0 = flat)"""

    @property
    def valid(self) -> Annotated[NDArray[numpy.bool_], dict(shape=(None,))]:
        """(N,) bool: >= 3 non-collinear neighbours"""

def voxel_downsample(points: Annotated[NDArray[numpy.float32], dict(shape=(None, 3), order='C', device='cpu', writable=False)], voxel_size: float, num_threads: int = 0, align_min_bound: bool = False) -> Annotated[NDArray[numpy.float32], dict(shape=(None, 3))]:
    """
    Voxel-grid downsampling with centroids. points: (N,3) float32 [m]; returns (M,3).
    """

def estimate_normals(points: Annotated[NDArray[numpy.float32], dict(shape=(None, 3), order='C', device='cpu', writable=False)], k_neighbors: int, radius: float, viewpoint: Annotated[NDArray[numpy.float64], dict(shape=(3), order='C')], num_threads: int) -> _Normals:
    """
    PCA normals of points (N,3) float32 [m] over k neighbours within radius [m].
    """

def statistical_outlier_removal(points: Annotated[NDArray[numpy.float32], dict(shape=(None, 3), order='C', device='cpu', writable=False)], k_neighbors: int, std_ratio: float, num_threads: int) -> Annotated[NDArray[numpy.int64], dict(shape=(None,))]:
    """Indices of the kept rows."""

def mls_smooth(points: Annotated[NDArray[numpy.float32], dict(shape=(None, 3), order='C', device='cpu', writable=False)], radius: float, num_threads: int, fit_voxel: float = 0.0) -> Annotated[NDArray[numpy.float32], dict(shape=(None, 3))]:
    """MLS-smoothed points (N,3)."""

def normal_space_sampling(normals: Annotated[NDArray[numpy.float64], dict(shape=(None, 3), order='C')], num_samples: int, bins_per_axis: int, seed: int) -> Annotated[NDArray[numpy.int64], dict(shape=(None,))]:
    """Sorted sample indices."""

def compute_fpfh(points: Annotated[NDArray[numpy.float32], dict(shape=(None, 3), order='C', device='cpu', writable=False)], normals: Annotated[NDArray[numpy.float64], dict(shape=(None, 3), order='C')], radius: float, max_neighbors: int, num_threads: int) -> Annotated[NDArray[numpy.float32], dict(shape=(None, 33))]:
    """FPFH descriptors (N,33) float32."""

class _PreparedCloud:
    @property
    def points(self) -> Annotated[NDArray[numpy.float32], dict(shape=(None, 3), order='C')]: ...

    @property
    def normals(self) -> Annotated[NDArray[numpy.float64], dict(shape=(None, 3), order='C')]: ...

    @property
    def normal_valid(self) -> Annotated[NDArray[numpy.bool_], dict(shape=(None,), order='C')]: ...

    @property
    def covariances(self) -> Annotated[NDArray[numpy.float64], dict(shape=(None, 9), order='C')]: ...

    @property
    def num_dropped(self) -> int: ...

    def __len__(self) -> int: ...

def prepare_cloud(points: Annotated[NDArray[numpy.float32], dict(shape=(None, 3), order='C', device='cpu', writable=False)], k_neighbors: int, radius: float, viewpoint: Annotated[NDArray[numpy.float64], dict(shape=(3), order='C')], point_sigma: float, num_threads: int) -> _PreparedCloud:
    """
    Finite points + k-d tree + normals + GICP covariances (see registration.prepare).
    """

class _RegistrationOptions:
    def __init__(self) -> None: ...

    @property
    def method(self) -> str: ...

    @method.setter
    def method(self, arg: str, /) -> None: ...

    @property
    def max_correspondence_distances(self) -> list[float]: ...

    @max_correspondence_distances.setter
    def max_correspondence_distances(self, arg: Sequence[float], /) -> None: ...

    @property
    def max_iterations(self) -> int: ...

    @max_iterations.setter
    def max_iterations(self, arg: int, /) -> None: ...

    @property
    def rotation_eps(self) -> float: ...

    @rotation_eps.setter
    def rotation_eps(self, arg: float, /) -> None: ...

    @property
    def translation_eps(self) -> float: ...

    @translation_eps.setter
    def translation_eps(self, arg: float, /) -> None: ...

    @property
    def point_sigma(self) -> float: ...

    @point_sigma.setter
    def point_sigma(self, arg: float, /) -> None: ...

    @property
    def loss(self) -> str: ...

    @loss.setter
    def loss(self, arg: str, /) -> None: ...

    @property
    def loss_scale(self) -> float: ...

    @loss_scale.setter
    def loss_scale(self, arg: float, /) -> None: ...

    @property
    def R_prior(self) -> Annotated[NDArray[numpy.float64], dict(shape=(3, 3), order='F')] | None: ...

    @R_prior.setter
    def R_prior(self, R: Annotated[NDArray[numpy.float64], dict(shape=(3, 3), order='F')] | None) -> None: ...

    @property
    def rotation_prior_sigma(self) -> float: ...

    @rotation_prior_sigma.setter
    def rotation_prior_sigma(self, arg: float, /) -> None: ...

    @property
    def lock_z(self) -> bool: ...

    @lock_z.setter
    def lock_z(self, arg: bool, /) -> None: ...

    @property
    def oriented(self) -> bool: ...

    @oriented.setter
    def oriented(self, arg: bool, /) -> None: ...

    @property
    def min_normal_cos(self) -> float: ...

    @min_normal_cos.setter
    def min_normal_cos(self, arg: float, /) -> None: ...

    @property
    def max_source(self) -> int: ...

    @max_source.setter
    def max_source(self, arg: int, /) -> None: ...

    @property
    def min_correspondences(self) -> int: ...

    @min_correspondences.setter
    def min_correspondences(self, arg: int, /) -> None: ...

    @property
    def num_threads(self) -> int: ...

    @num_threads.setter
    def num_threads(self, arg: int, /) -> None: ...

class _RegistrationResult:
    @property
    def T_target_source(self) -> Annotated[NDArray[numpy.float64], dict(shape=(4, 4), order='F')]: ...

    @property
    def converged(self) -> bool: ...

    @property
    def status(self) -> str: ...

    @property
    def iterations(self) -> int: ...

    @property
    def num_inliers(self) -> int: ...

    @property
    def fitness(self) -> float: ...

    @property
    def inlier_rmse(self) -> float: ...

    @property
    def residual_rmse(self) -> float: ...

    @property
    def final_error(self) -> float: ...

    @property
    def information(self) -> Annotated[NDArray[numpy.float64], dict(shape=(6, 6), order='F')]: ...

    @property
    def condition(self) -> float: ...

def register_local(source: _PreparedCloud, target: _PreparedCloud, T_init: Annotated[NDArray[numpy.float64], dict(shape=(4, 4), order='F')], options: _RegistrationOptions) -> _RegistrationResult:
    """Local registration of prepared clouds (see registration.register)."""

class _GlobalOptions:
    def __init__(self) -> None: ...

    @property
    def normal_radius(self) -> float: ...

    @normal_radius.setter
    def normal_radius(self, arg: float, /) -> None: ...

    @property
    def feature_radius(self) -> float: ...

    @feature_radius.setter
    def feature_radius(self, arg: float, /) -> None: ...

    @property
    def max_neighbors(self) -> int: ...

    @max_neighbors.setter
    def max_neighbors(self, arg: int, /) -> None: ...

    @property
    def inlier_distance(self) -> float: ...

    @inlier_distance.setter
    def inlier_distance(self, arg: float, /) -> None: ...

    @property
    def edge_length_ratio(self) -> float: ...

    @edge_length_ratio.setter
    def edge_length_ratio(self, arg: float, /) -> None: ...

    @property
    def mutual_filter(self) -> bool: ...

    @mutual_filter.setter
    def mutual_filter(self, arg: bool, /) -> None: ...

    @property
    def max_iterations(self) -> int: ...

    @max_iterations.setter
    def max_iterations(self, arg: int, /) -> None: ...

    @property
    def confidence(self) -> float: ...

    @confidence.setter
    def confidence(self, arg: float, /) -> None: ...

    @property
    def up_source(self) -> Annotated[NDArray[numpy.float64], dict(shape=(3), order='C')]: ...

    @up_source.setter
    def up_source(self, arg: Annotated[NDArray[numpy.float64], dict(shape=(3), order='C')], /) -> None: ...

    @property
    def up_target(self) -> Annotated[NDArray[numpy.float64], dict(shape=(3), order='C')]: ...

    @up_target.setter
    def up_target(self, arg: Annotated[NDArray[numpy.float64], dict(shape=(3), order='C')], /) -> None: ...

    @property
    def R_prior(self) -> Annotated[NDArray[numpy.float64], dict(shape=(3, 3), order='F')] | None: ...

    @R_prior.setter
    def R_prior(self, R: Annotated[NDArray[numpy.float64], dict(shape=(3, 3), order='F')] | None) -> None: ...

    @property
    def rotation_tolerance(self) -> float: ...

    @rotation_tolerance.setter
    def rotation_tolerance(self, arg: float, /) -> None: ...

    @property
    def viewpoint_source(self) -> Annotated[NDArray[numpy.float64], dict(shape=(3), order='C')]: ...

    @viewpoint_source.setter
    def viewpoint_source(self, arg: Annotated[NDArray[numpy.float64], dict(shape=(3), order='C')], /) -> None: ...

    @property
    def viewpoint_target(self) -> Annotated[NDArray[numpy.float64], dict(shape=(3), order='C')]: ...

    @viewpoint_target.setter
    def viewpoint_target(self, arg: Annotated[NDArray[numpy.float64], dict(shape=(3), order='C')], /) -> None: ...

    @property
    def twin_turns(self) -> list[float]: ...

    @twin_turns.setter
    def twin_turns(self, arg: Sequence[float], /) -> None: ...

    @property
    def twin_tolerance(self) -> float: ...

    @twin_tolerance.setter
    def twin_tolerance(self, arg: float, /) -> None: ...

    @property
    def seed(self) -> int: ...

    @seed.setter
    def seed(self, arg: int, /) -> None: ...

    @property
    def num_threads(self) -> int: ...

    @num_threads.setter
    def num_threads(self, arg: int, /) -> None: ...

class _GlobalTwin:
    @property
    def turn(self) -> float: ...

    @property
    def T_target_source(self) -> Annotated[NDArray[numpy.float64], dict(shape=(4, 4), order='F')]: ...

    @property
    def num_inlier_correspondences(self) -> int: ...

    @property
    def geometric_score(self) -> int: ...

    @property
    def fitness(self) -> float: ...

    @property
    def inlier_rmse(self) -> float: ...

class _GlobalResult:
    @property
    def T_target_source(self) -> Annotated[NDArray[numpy.float64], dict(shape=(4, 4), order='F')]: ...

    @property
    def success(self) -> bool: ...

    @property
    def status(self) -> str: ...

    @property
    def num_correspondences(self) -> int: ...

    @property
    def num_inlier_correspondences(self) -> int: ...

    @property
    def iterations(self) -> int: ...

    @property
    def fitness(self) -> float: ...

    @property
    def inlier_rmse(self) -> float: ...

    @property
    def geometric_score(self) -> int: ...

    @property
    def twins(self) -> list[_GlobalTwin]: ...

def register_global(source: Annotated[NDArray[numpy.float32], dict(shape=(None, 3), order='C', device='cpu', writable=False)], target: Annotated[NDArray[numpy.float32], dict(shape=(None, 3), order='C', device='cpu', writable=False)], options: _GlobalOptions) -> _GlobalResult:
    """FPFH + RANSAC global registration (see registration.register_global)."""

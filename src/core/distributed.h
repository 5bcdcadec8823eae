// Distribution over processes with MPI (issue 10; docs/cluster.md). Compiled with or without MPI:
// without MESO_WITH_MPI (or when the process was not started by mpirun / srun) everything here is
// the single-process case (rank 0 of 1) and costs nothing.
//
// MPI is initialised only when a launcher started the process (Open MPI's OMPI_COMM_WORLD_SIZE,
// PMI/PMIx as set by srun: PMI_SIZE, PMIX_RANK), so a plain `meso ...` never touches MPI.
// Threads: MPI_THREAD_FUNNELED; only the main thread calls MPI (TBB workers never do).
#pragma once
#include <cstddef>
#include <cstdint>
#include <string>

namespace meso::dist {

/// Initialises MPI if a launcher started this process (idempotent); call first in main().
void init(int *argc, char ***argv);
/// MPI_Finalize if init() initialised it; call before a normal exit.
void finalize();
/// True when built with MPI and running under a launcher (even with one rank).
bool active();
int rank();
int size();
/// Ranks on this node (MPI_COMM_TYPE_SHARED; 1 without MPI): threads default to cores / this.
int local_size();
/// Ends every rank: prints "meso: error (rank r of n): message" and MPI_Abort(code). Without MPI
/// it only returns (the caller exits as a single process would).
void abort_all(const std::string &message, int code = 1);

/// In-place element-wise sum over all ranks; the result lands on rank 0 only (MPI_Reduce).
void reduce_sum_to_root(double *data, size_t n);
void reduce_sum_to_root(uint64_t *data, size_t n);
/// Element-wise sum over all ranks, result on every rank.
void allreduce_sum(double *data, size_t n);
void allreduce_sum(uint32_t *data, size_t n);
/// Maximum over all ranks, result on every rank.
double allreduce_max(double v);
/// Rank 0's value on every rank (a decision all ranks must share, e.g. "render another pass").
bool broadcast(bool v);
void broadcast(double *data, size_t n);
/// Synchronise all ranks.
void barrier();

/// "MPI (Open MPI 4.1.4)" or "no MPI" for `meso info`.
std::string describe();

}  // namespace meso::dist

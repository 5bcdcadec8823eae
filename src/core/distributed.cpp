#include "core/distributed.h"
#include <cstdio>
#include <cstdlib>
#include <algorithm>
#include <fmt/format.h>
#ifdef MESO_WITH_MPI
#include <mpi.h>
#endif

namespace meso::dist {

namespace {
bool g_active = false;
[[maybe_unused]] bool g_initialised_here = false;  // unused without MPI
int g_rank = 0, g_size = 1, g_local = 1;

bool launched_by_mpi() {
    for (const char *v : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK", "MPI_LOCALNRANKS"})
        if (std::getenv(v)) return true;
    return false;
}
}  // namespace

#ifdef MESO_WITH_MPI

void init(int *argc, char ***argv) {
    if (g_active || !launched_by_mpi()) return;
    int already = 0;
    MPI_Initialized(&already);
    if (!already) {
        int provided = 0;
        MPI_Init_thread(argc, argv, MPI_THREAD_FUNNELED, &provided);
        g_initialised_here = true;
    }
    g_active = true;
    MPI_Comm_rank(MPI_COMM_WORLD, &g_rank);
    MPI_Comm_size(MPI_COMM_WORLD, &g_size);
    MPI_Comm local;
    MPI_Comm_split_type(MPI_COMM_WORLD, MPI_COMM_TYPE_SHARED, g_rank, MPI_INFO_NULL, &local);
    MPI_Comm_size(local, &g_local);
    MPI_Comm_free(&local);
}

void finalize() {
    if (g_initialised_here) {
        int done = 0;
        MPI_Finalized(&done);
        if (!done) MPI_Finalize();
    }
    g_active = false;
    g_initialised_here = false;
}

void abort_all(const std::string &message, int code) {
    std::fprintf(stderr, "meso: error (rank %d of %d): %s\n", g_rank, g_size, message.c_str());
    std::fflush(stderr);
    if (g_active) MPI_Abort(MPI_COMM_WORLD, code);
}

void reduce_sum_to_root(double *data, size_t n) {
    if (!g_active || g_size == 1) return;
    constexpr size_t chunk = size_t(1) << 26;  // MPI counts are int
    for (size_t o = 0; o < n; o += chunk) {
        const int c = int(std::min(chunk, n - o));
        if (g_rank == 0) MPI_Reduce(MPI_IN_PLACE, data + o, c, MPI_DOUBLE, MPI_SUM, 0, MPI_COMM_WORLD);
        else MPI_Reduce(data + o, nullptr, c, MPI_DOUBLE, MPI_SUM, 0, MPI_COMM_WORLD);
    }
}

void reduce_sum_to_root(uint64_t *data, size_t n) {
    if (!g_active || g_size == 1) return;
    if (g_rank == 0) MPI_Reduce(MPI_IN_PLACE, data, int(n), MPI_UINT64_T, MPI_SUM, 0, MPI_COMM_WORLD);
    else MPI_Reduce(data, nullptr, int(n), MPI_UINT64_T, MPI_SUM, 0, MPI_COMM_WORLD);
}

void allreduce_sum(double *data, size_t n) {
    if (!g_active || g_size == 1) return;
    constexpr size_t chunk = size_t(1) << 26;  // MPI counts are int
    for (size_t o = 0; o < n; o += chunk)
        MPI_Allreduce(MPI_IN_PLACE, data + o, int(std::min(chunk, n - o)), MPI_DOUBLE, MPI_SUM, MPI_COMM_WORLD);
}

void allreduce_sum(uint32_t *data, size_t n) {
    if (!g_active || g_size == 1) return;
    MPI_Allreduce(MPI_IN_PLACE, data, int(n), MPI_UINT32_T, MPI_SUM, MPI_COMM_WORLD);
}

double allreduce_max(double v) {
    if (!g_active || g_size == 1) return v;
    MPI_Allreduce(MPI_IN_PLACE, &v, 1, MPI_DOUBLE, MPI_MAX, MPI_COMM_WORLD);
    return v;
}

bool broadcast(bool v) {
    if (!g_active || g_size == 1) return v;
    int i = v ? 1 : 0;
    MPI_Bcast(&i, 1, MPI_INT, 0, MPI_COMM_WORLD);
    return i != 0;
}

void broadcast(double *data, size_t n) {
    if (!g_active || g_size == 1) return;
    MPI_Bcast(data, int(n), MPI_DOUBLE, 0, MPI_COMM_WORLD);
}

void barrier() {
    if (g_active && g_size > 1) MPI_Barrier(MPI_COMM_WORLD);
}

std::string describe() {
    char lib[MPI_MAX_LIBRARY_VERSION_STRING];
    int len = 0;
    MPI_Get_library_version(lib, &len);
    std::string s(lib, size_t(len));
    const size_t nl = s.find_first_of(",\n");
    if (nl != std::string::npos) s = s.substr(0, nl);
    return g_active ? fmt::format("MPI ({}), rank {} of {}", s, g_rank, g_size) : fmt::format("MPI ({}), not launched by mpirun", s);
}

#else  // no MPI: one process

void init(int *, char ***) {
    if (launched_by_mpi())
        std::fprintf(stderr, "meso: warning: started by an MPI launcher, but this build has no MPI (configure with "
                             "-DMESO_WITH_MPI=ON and libopenmpi-dev): every rank renders everything alone\n");
}
void finalize() {}
void abort_all(const std::string &, int) {}
void reduce_sum_to_root(double *, size_t) {}
void reduce_sum_to_root(uint64_t *, size_t) {}
void allreduce_sum(double *, size_t) {}
void allreduce_sum(uint32_t *, size_t) {}
double allreduce_max(double v) { return v; }
bool broadcast(bool v) { return v; }
void broadcast(double *, size_t) {}
void barrier() {}
std::string describe() { return "no MPI (built without MESO_WITH_MPI)"; }

#endif

bool active() { return g_active; }
int rank() { return g_rank; }
int size() { return g_size; }
int local_size() { return g_local; }

}  // namespace meso::dist

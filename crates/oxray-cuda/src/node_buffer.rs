//! A GAS's node array in device memory, after a 64-byte header that holds the GAS's traversable
//! descriptor (`__oxray_Traversable` in `oxray_device.h`) once a pipeline asks for its handle.
//!
//! The handle is then the header's address and the nodes start 64 bytes after it, so a
//! pipeline's walk of a GAS at the root computes each node's address from the handle instead
//! of loading the node array's address from the descriptor at every step: a dependent load a
//! node that the query kernels, which have the address in their parameters, do not pay
//! (docs/BENCHMARKS.md, "The pipeline, ninth round"). The header costs 64 bytes a structure.

use crate::context::CudaContext;
use crate::error::{driver, CudaError};
use cudarc::driver::{CudaSlice, CudaView, CudaViewMut, DevicePtr};

/// Words before the first node: one traversable descriptor.
pub(crate) const HEADER_WORDS: usize = 16;

/// The node array of a GAS behind its descriptor's header.
#[derive(Debug)]
pub(crate) struct NodeBuffer {
    words: CudaSlice<u32>,
}

impl NodeBuffer {
    /// Copies `nodes` to the device after a zeroed header.
    pub(crate) fn upload(ctx: &CudaContext, nodes: &[u32]) -> Result<NodeBuffer, CudaError> {
        let mut words = ctx
            .stream
            .alloc_zeros::<u32>(HEADER_WORDS + nodes.len())
            .map_err(driver("allocating BVH nodes"))?;
        if !nodes.is_empty() {
            ctx.stream
                .memcpy_htod(nodes, &mut words.slice_mut(HEADER_WORDS..))
                .map_err(driver("copying BVH nodes to the device"))?;
        }
        Ok(NodeBuffer { words })
    }

    /// Room for `len` node words after the header, left for kernels to write.
    pub(crate) fn uninit(ctx: &CudaContext, len: usize) -> Result<NodeBuffer, CudaError> {
        // SAFETY: the memory is left uninitialised; the header is written before a handle to
        // it is given out (`write_header`), and every caller hands the nodes to kernels that
        // write each node the tree links before anything reads it, in stream order.
        let words = unsafe { ctx.stream.alloc::<u32>(HEADER_WORDS + len.max(1)) }
            .map_err(driver("allocating BVH nodes"))?;
        Ok(NodeBuffer { words })
    }

    /// A copy on the device of `self` (header and nodes).
    pub(crate) fn duplicate(&self, ctx: &CudaContext) -> Result<NodeBuffer, CudaError> {
        let words = ctx
            .stream
            .clone_dtod(&self.words)
            .map_err(driver("copying BVH nodes on the device"))?;
        Ok(NodeBuffer { words })
    }

    /// The node words.
    pub(crate) fn nodes(&self) -> CudaView<'_, u32> {
        self.words.slice(HEADER_WORDS..)
    }

    /// The node words, for kernels that write them.
    pub(crate) fn nodes_mut(&mut self) -> CudaViewMut<'_, u32> {
        self.words.slice_mut(HEADER_WORDS..)
    }

    /// The device address of the first node.
    pub(crate) fn nodes_address(&self, ctx: &CudaContext) -> u64 {
        self.header_address(ctx) + 4 * HEADER_WORDS as u64
    }

    /// The device address of the header: the GAS's handle once `write_header` has run.
    pub(crate) fn header_address(&self, ctx: &CudaContext) -> u64 {
        let (p, _g) = self.words.device_ptr(&ctx.stream);
        p
    }

    /// Writes the traversable descriptor into the header and waits for the copy.
    ///
    /// Takes `&self` because the descriptor is written on first use of the handle, from a
    /// shared reference to the GAS; nothing else writes the header, no kernel reads it before a
    /// handle to it is given out, and the caller holds the GAS's program-view lock, so no two
    /// writes race.
    pub(crate) fn write_header(
        &self,
        ctx: &CudaContext,
        descriptor: &[u32; HEADER_WORDS],
    ) -> Result<u64, CudaError> {
        let address = self.header_address(ctx);
        // SAFETY: `address` is the start of this buffer's allocation, which holds at least
        // HEADER_WORDS words and lives as long as `self`; the copy is of 64 bytes from a live
        // host array, and is complete before the function returns (the stream is synchronised),
        // so the host array outlives it. Kernels only read the header through handles, which
        // are given out after this returns.
        unsafe {
            cudarc::driver::result::memcpy_htod_async(
                address,
                &descriptor[..],
                ctx.stream.cu_stream(),
            )
        }
        .map_err(driver("copying a traversable descriptor"))?;
        ctx.synchronize()?;
        Ok(address)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gas::{descriptor_words, CudaGas, DESCRIPTOR_GAS};
    use crate::program::DEVICE_HEADER;
    use oxray_bvh::GasData;
    use oxray_core::{BuildOptions, TriangleInput, VertexBuffer};

    #[test]
    fn the_header_holds_one_descriptor_and_the_device_walk_steps_over_it() {
        let d = descriptor_words(DESCRIPTOR_GAS, 1, 1, 0, 0, 0, 0);
        assert_eq!(d.len(), HEADER_WORDS);
        assert!(
            DEVICE_HEADER.contains(r#"asm volatile("add.u64 %0, %1, 64;" : "=l"(v) : "l"(n.g));"#)
        );
        assert!(DEVICE_HEADER.contains("static_assert(sizeof(__oxray_Traversable) == 64"));
    }

    fn words_at(ctx: &CudaContext, view: &CudaView<'_, u32>, n: usize) -> Vec<u32> {
        let mut out = vec![0u32; n];
        ctx.stream
            .memcpy_dtoh(&view.slice(..n), &mut out[..])
            .unwrap();
        ctx.synchronize().unwrap();
        out
    }

    /// On a device (skipped without one unless `OXRAY_REQUIRE_GPU` is set): a GAS's handle is
    /// the start of its node buffer, the descriptor there names the nodes right after it, and a
    /// copy of the GAS gets a header of its own.
    #[test]
    fn a_gas_handle_is_the_header_before_its_nodes() {
        let ctx = match CudaContext::new() {
            Ok(c) => c,
            Err(e) if e.is_unavailable() && std::env::var_os("OXRAY_REQUIRE_GPU").is_none() => {
                println!("skipping: {e}");
                return;
            }
            Err(e) => panic!("CUDA is present but unusable: {e}"),
        };
        let v = [
            [0.0f32, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 1.0, 0.5],
        ];
        let i = [[0u32, 1, 2], [1, 3, 2]];
        let input =
            TriangleInput::new(VertexBuffer::f32x3(&v)).indices(oxray_core::IndexBuffer::u32x3(&i));
        let (data, tree) = GasData::build_with_tree(&BuildOptions::default(), &[input.into()])
            .expect("a valid build");
        let gas = CudaGas::upload(&ctx, &data, &tree).unwrap();
        for g in [&gas, &gas.duplicate().unwrap()] {
            let handle = g.optix_handle().unwrap();
            assert_eq!(handle, g.nodes.header_address(&ctx));
            assert_eq!(g.nodes.nodes_address(&ctx), handle + 64);
            let mut header = [0u32; HEADER_WORDS];
            let whole = g.nodes.words.slice(..);
            header.copy_from_slice(&words_at(&ctx, &whole, HEADER_WORDS));
            assert_eq!(header[0], DESCRIPTOR_GAS);
            let nodes = u64::from(header[2]) | u64::from(header[3]) << 32;
            assert_eq!(
                nodes,
                handle + 64,
                "the descriptor names the nodes after it"
            );
            // The query kernels' view of the nodes is what follows the header.
            let after = words_at(&ctx, &whole.slice(HEADER_WORDS..), 16);
            assert_eq!(after, words_at(&ctx, &g.nodes.nodes(), 16));
            // The handle is made once.
            assert_eq!(g.optix_handle().unwrap(), handle);
        }
    }
}

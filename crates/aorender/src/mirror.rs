//! Structs that Rust and WGSL share, each declared once: [`gpu_struct!`] defines the
//! `#[repr(C)]` Rust struct and describes its fields, from which the WGSL declaration is
//! generated (`gpu::shaders`), so the two cannot disagree on a name, a type or an order.
//! The layout test compares every field's offset with naga's layout of the WGSL.

/// A field of a shared struct.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Field {
    /// Name, the same in Rust and WGSL.
    pub name: &'static str,
    /// WGSL type.
    pub wgsl: &'static str,
    /// Byte offset in the Rust struct (`offset_of!`).
    pub offset: usize,
    /// One line saying what it holds, copied into the WGSL as a comment.
    pub doc: &'static str,
}

/// A `#[repr(C)]` struct with a WGSL twin of the same layout.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StructLayout {
    /// The WGSL struct's name.
    pub wgsl_name: &'static str,
    /// Size of the Rust struct.
    pub size: usize,
    /// Its fields, in order.
    pub fields: &'static [Field],
}

impl StructLayout {
    /// The WGSL declaration.
    pub fn wgsl(&self) -> String {
        let mut s = format!("struct {} {{\n", self.wgsl_name);
        for f in self.fields {
            s += &format!("    {}: {},", f.name, f.wgsl);
            if !f.doc.is_empty() {
                s += &format!(" // {}", f.doc);
            }
            s += "\n";
        }
        s += "}\n";
        s
    }
}

/// Implemented by the structs [`gpu_struct!`] declares.
pub trait GpuStruct: bytemuck::Pod {
    /// The layout shared with WGSL.
    const LAYOUT: StructLayout;
}

/// Declares a `#[repr(C)]`, `Pod` struct and its [`StructLayout`]: every field is written
/// `name: RustType = "wgsl_type"` after its doc comment, whose first line becomes the
/// WGSL comment.
macro_rules! gpu_struct {
    (
        $(#[doc = $doc:literal])*
        pub struct $name:ident as $wgsl_name:literal {
            $(
                #[doc = $field_doc:literal]
                pub $field:ident: $ty:ty = $wgsl:literal,
            )*
        }
    ) => {
        $(#[doc = $doc])*
        #[repr(C)]
        #[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
        pub struct $name {
            $(
                #[doc = $field_doc]
                pub $field: $ty,
            )*
        }

        impl $crate::mirror::GpuStruct for $name {
            const LAYOUT: $crate::mirror::StructLayout = $crate::mirror::StructLayout {
                wgsl_name: $wgsl_name,
                size: std::mem::size_of::<$name>(),
                fields: &[$(
                    $crate::mirror::Field {
                        name: stringify!($field),
                        wgsl: $wgsl,
                        offset: std::mem::offset_of!($name, $field),
                        doc: $field_doc.trim_ascii(),
                    },
                )*],
            };
        }
    };
}
pub(crate) use gpu_struct;

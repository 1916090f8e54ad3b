//! One declaration per variable: [`variables!`](crate::variables!) writes a model's handle struct
//! and the function that adds its variables to a [`TableBuilder`], from one list.
//!
//! Each line of the list names a field, its handle type and the declaration of the variable
//! (name, causality, variability, size, unit, start, description, check, dependencies: a
//! [`Decl`]). From that one line come the typed handle the wiring uses (the struct field), the
//! variable table (value reference, start value, checks on set), and through the table the
//! modelDescription.xml and the documentation page ([`crate::xml`], [`crate::package`]). The
//! order of the lines is the order of the variables in the table and the XML.
//!
//! ```
//! use fmu::{RealVar, StrVar, TableBuilder as T};
//!
//! fmu::variables! {
//!     /// Handles of every variable.
//!     #[derive(Debug, Clone, Copy)]
//!     pub struct Vars(b, n: usize) {
//!         name: StrVar = T::string("name").structural().start_str("demo").describe("Variant"),
//!         u: RealVar = T::real("u").input().len(n).unit("m").start(0.0).describe("Input"),
//!         y: RealVar = T::real("y").output().len(n).unit("m").describe("Output"),
//!     }
//! }
//!
//! let (table, vars) = T::declare(|b| Vars::add_to(b, 3)).unwrap();
//! assert_eq!(table.variables().len(), 3);
//! assert_eq!(table.by_name("y").unwrap().vr as usize, vars.y.slot); // a Real's slot is its value reference
//! ```
//!
//! A line may instead add a group of variables declared elsewhere (`field: Group => expr`),
//! where `expr` uses the builder named before the arguments (`b` above), e.g.
//! `segments: ParamVars => ParamVars::add_to::<V>(b, &V::defaults())`.

use crate::error::FmuError;
use crate::variables::{BoolVar, Decl, IntVar, RealVar, StrVar, TableBuilder, VariableTable};

/// A typed handle that a [`Decl`] of its base type becomes when added to a [`TableBuilder`].
pub trait Handle: Sized {
    /// Adds `decl` to the builder and returns its handle. A declaration of another base type
    /// is reported by [`TableBuilder::build`].
    fn add(builder: &mut TableBuilder, decl: Decl) -> Self;
}

impl Handle for RealVar {
    fn add(builder: &mut TableBuilder, decl: Decl) -> Self {
        builder.add_real(decl)
    }
}

impl Handle for IntVar {
    fn add(builder: &mut TableBuilder, decl: Decl) -> Self {
        builder.add_integer(decl)
    }
}

impl Handle for BoolVar {
    fn add(builder: &mut TableBuilder, decl: Decl) -> Self {
        builder.add_boolean(decl)
    }
}

impl Handle for StrVar {
    fn add(builder: &mut TableBuilder, decl: Decl) -> Self {
        builder.add_string(decl)
    }
}

impl TableBuilder {
    /// Runs `declare` on a new builder and builds the table: the one call a model's
    /// [`crate::Model::new`] needs, `TableBuilder::declare(|b| Vars::add_to(b, ...))`.
    ///
    /// # Errors
    /// The checks of [`TableBuilder::build`].
    pub fn declare<V>(
        declare: impl FnOnce(&mut TableBuilder) -> V,
    ) -> Result<(VariableTable, V), FmuError> {
        let mut builder = TableBuilder::new();
        let vars = declare(&mut builder);
        Ok((builder.build()?, vars))
    }
}

/// Declares a struct of variable handles and its `add_to` function from one list; see the
/// [module documentation](crate::declare).
///
/// ```text
/// fmu::variables! {
///     /// doc
///     #[derive(...)]
///     pub struct Vars<V: Bound>(b, layout: &Layout) {
///         field: RealVar = <a Decl>,         // one variable
///         pub other: IntVar = <a Decl>,      // a field may have a visibility
///         group: Group => <expr using b>,    // variables declared by another function
///     }
/// }
/// ```
///
/// generates `pub struct Vars { field: RealVar, group: Group }` and
/// `impl Vars { pub fn add_to<V: Bound>(b: &mut TableBuilder, layout: &Layout) -> Vars }`,
/// which adds the variables in the order written. The generics (optional) belong to `add_to`.
#[macro_export]
macro_rules! variables {
    (
        $(#[$meta:meta])*
        $vis:vis struct $name:ident $(< $($g:ident : $gb:path),+ >)?
            ($b:ident $(, $arg:ident : $argty:ty)* $(,)?)
        {
            $(
                $(#[$fmeta:meta])*
                $fvis:vis $field:ident : $fty:ty $(= $decl:expr)? $(=> $group:expr)?
            ),* $(,)?
        }
    ) => {
        $(#[$meta])*
        $vis struct $name {
            $( $(#[$fmeta])* $fvis $field: $fty, )*
        }

        impl $name {
            /// Adds every variable to the builder, in the order declared, and returns the
            /// handles.
            #[allow(clippy::too_many_lines, dead_code)]
            $vis fn add_to $(< $($g : $gb),+ >)? (
                $b: &mut $crate::TableBuilder $(, $arg: $argty)*
            ) -> Self {
                Self {
                    $( $field: $crate::__variable_init!($b, $fty $(, = $decl)? $(, => $group)?), )*
                }
            }
        }
    };
}

/// One field of [`variables!`]: a declaration added through its handle type, or a group.
#[doc(hidden)]
#[macro_export]
macro_rules! __variable_init {
    ($b:ident, $fty:ty, = $decl:expr) => {
        <$fty as $crate::declare::Handle>::add($b, $decl)
    };
    ($b:ident, $fty:ty, => $group:expr) => {
        $group
    };
}

#[cfg(test)]
mod tests {
    use crate::variables::{BoolVar, IntVar, RealVar, TableBuilder as T};

    crate::variables! {
        /// Test handles.
        #[derive(Debug, Clone, Copy)]
        struct Group(b, scale: f64) {
            gain: RealVar = T::real("gain").parameter().start(scale).describe("Gain"),
            on: BoolVar = T::boolean("on").parameter().start_bool(true).describe("Switch"),
        }
    }

    crate::variables! {
        /// Test handles.
        #[derive(Debug, Clone, Copy)]
        struct Vars(b, n: usize) {
            count: IntVar = T::integer("count").structural().start_int(3).describe("Count"),
            u: RealVar = T::real("u").input().len(n).unit("m").start(0.0).describe("Input"),
            group: Group => Group::add_to(b, 2.0),
            y: RealVar = T::real("y").output().len(n).unit("m").describe("Output"),
        }
    }

    #[test]
    fn one_list_gives_the_handles_and_the_table_in_order() {
        let (table, vars) = T::declare(|b| Vars::add_to(b, 4)).expect("table");
        let names: Vec<&str> = table.variables().iter().map(|v| v.name.as_str()).collect();
        assert_eq!(names, ["count", "u", "gain", "on", "y"]);
        let u = table.by_name("u").expect("u");
        assert_eq!((u.len, u.vr as usize), (4, vars.u.slot));
        assert_eq!(table.by_name("y").expect("y").vr as usize, vars.y.slot);
        assert_eq!(
            table.by_name("gain").expect("gain").vr as usize,
            vars.group.gain.slot
        );
        let values = table.initial_values();
        assert_eq!(values.scalar(vars.group.gain), 2.0);
        assert!(values.boolean(vars.group.on));
        assert_eq!(values.integer(vars.count), 3);
    }

    #[test]
    fn a_declaration_of_the_wrong_type_is_refused() {
        crate::variables! {
            #[allow(dead_code)]
            #[derive(Debug)]
            struct Wrong(b) {
                x: IntVar = T::real("x").parameter().start(1.0).describe("Real, held as Integer"),
            }
        }
        let err = T::declare(Wrong::add_to).expect_err("type mismatch");
        assert!(err.to_string().contains("x: declared as Real"), "{err}");
    }
}

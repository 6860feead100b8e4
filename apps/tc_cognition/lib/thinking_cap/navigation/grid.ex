defmodule ThinkingCap.Navigation.Grid do
  @moduledoc """
  A planning grid: which cells a robot may not enter, and what the others
  cost. One byte per cell, row-major from the bottom row (cell
  `{col, row}` is byte `row * width + col`): 0 passable, 1 blocked, 2 to
  255 passable at a cost (a cost map's band round its obstacles, see
  below); `origin` is the world position of the lower-left corner of
  cell `{0, 0}`, `resolution` the cell size in metres (axis-aligned: no
  rotation).

  The planners (`ThinkingCap.Navigation.AStar`,
  `ThinkingCap.Navigation.DStarLite`) search it 8-connected with octile
  costs and no corner cutting; the map builders of
  `ThinkingCap.Navigation` produce it. A step between cells of bytes `a`
  and `b` costs its length (1 or √2) times `1 + (p(a) + p(b)) / 16`,
  where `p(v)` is `v` from 2 up and 0 otherwise: a path through cells of
  cost 255 costs about 33 times its length there, through cells of cost
  8 twice.
  `ThinkingCap.Navigation.PathPlanner` writes such a band beside the
  grown obstacles, so that its plans keep off them where there is room.
  """

  @enforce_keys [:width, :height, :cells]
  defstruct [:width, :height, :cells, resolution: 1.0, origin: {0.0, 0.0}]

  @type cell :: {non_neg_integer(), non_neg_integer()}
  @type t :: %__MODULE__{
          width: pos_integer(),
          height: pos_integer(),
          cells: binary(),
          resolution: float(),
          origin: {float(), float()}
        }

  @doc "A grid of `width` × `height` cells, every one passable unless `cells` says otherwise."
  @spec new(pos_integer(), pos_integer(), keyword()) :: t()
  def new(width, height, opts \\ []) do
    cells = Keyword.get(opts, :cells, :binary.copy(<<0>>, width * height))

    unless byte_size(cells) == width * height,
      do: raise(ArgumentError, "grid cells: #{byte_size(cells)} bytes for #{width}×#{height}")

    %__MODULE__{
      width: width,
      height: height,
      cells: cells,
      resolution: Keyword.get(opts, :resolution, 1.0) * 1.0,
      origin: Keyword.get(opts, :origin, {0.0, 0.0})
    }
  end

  @doc "Whether `cell` is inside the grid and passable (at any cost)."
  @spec passable?(t(), cell()) :: boolean()
  def passable?(%__MODULE__{width: w, height: h, cells: cells}, {col, row})
      when col >= 0 and row >= 0 and col < w and row < h,
      do: :binary.at(cells, row * w + col) != 1

  def passable?(_grid, _cell), do: false

  @doc "Sets cells blocked (`true`) or passable (`false`)."
  @spec put(t(), [cell()], boolean()) :: t()
  def put(%__MODULE__{width: w, cells: bytes} = grid, cells, blocked?) do
    value = if blocked?, do: <<1>>, else: <<0>>

    # the grid's bytes between the cells set, and the value at each: one
    # copy of the grid, however many cells
    {parts, from} =
      for({col, row} = cell <- cells, inside?(grid, cell), uniq: true, do: row * w + col)
      |> Enum.sort()
      |> Enum.reduce({[], 0}, fn i, {parts, from} ->
        {[value, binary_part(bytes, from, i - from) | parts], i + 1}
      end)

    rest = binary_part(bytes, from, byte_size(bytes) - from)
    %{grid | cells: IO.iodata_to_binary(Enum.reverse([rest | parts]))}
  end

  @doc "Whether `cell` is inside the grid."
  @spec inside?(t(), cell()) :: boolean()
  def inside?(%__MODULE__{width: w, height: h}, {col, row}),
    do: col >= 0 and row >= 0 and col < w and row < h

  @doc "The cell containing world point `{x, y}`."
  @spec cell_of(t(), {number(), number()}) :: cell()
  def cell_of(%__MODULE__{origin: {ox, oy}, resolution: r}, {x, y}),
    do: {floor((x - ox) / r), floor((y - oy) / r)}

  @doc "The world position of a cell's centre."
  @spec centre(t(), cell()) :: {float(), float()}
  def centre(%__MODULE__{origin: {ox, oy}, resolution: r}, {col, row}),
    do: {ox + (col + 0.5) * r, oy + (row + 0.5) * r}

  @doc """
  Sets many cells at once, each blocked (`true`) or passable (`false`):
  like `put/3` for a list of `{cell, blocked?}` changes (a later change of
  the same cell wins; cells outside the grid are ignored), in one copy of
  the grid's bytes whatever the number of changes.
  """
  @spec update(t(), [{cell(), boolean()}]) :: t()
  def update(%__MODULE__{} = grid, []), do: grid

  def update(%__MODULE__{width: w, cells: cells} = grid, changes) do
    packed =
      for {{col, row} = cell, blocked?} <- changes,
          inside?(grid, cell),
          into: <<>>,
          do: <<row * w + col::signed-32-native, if(blocked?, do: 1, else: 0)::signed-32-native>>

    %{grid | cells: ThinkingCap.Navigation.Core.GridNif.patch(cells, packed)}
  end
end
